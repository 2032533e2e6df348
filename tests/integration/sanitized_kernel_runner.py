"""Run pytest with canfdi._ckernel taken from a given file (the C kernel built with
AddressSanitizer and UndefinedBehaviorSanitizer by test_sanitized_kernel.py), not the one
installed: ``python sanitized_kernel_runner.py KERNEL.so PYTEST-ARGS...`` under LD_PRELOAD of
the sanitizers' runtime. The module is put in sys.modules before canfdi.core.kernel imports
it, so every kernel choice of c in the tests runs the sanitized build."""

from __future__ import annotations

import importlib.util
import sys


def main() -> int:
    spec = importlib.util.spec_from_file_location("canfdi._ckernel", sys.argv[1])
    if spec is None or spec.loader is None:
        print(f"cannot load {sys.argv[1]}", file=sys.stderr)
        return 3
    module = importlib.util.module_from_spec(spec)
    sys.modules["canfdi._ckernel"] = module
    spec.loader.exec_module(module)
    import canfdi
    from canfdi.core import kernel

    canfdi._ckernel = module
    if kernel._ckernel is not module:
        print("the sanitized kernel did not replace the installed one", file=sys.stderr)
        return 3
    import pytest

    return int(pytest.main(sys.argv[2:]))


if __name__ == "__main__":
    sys.exit(main())
