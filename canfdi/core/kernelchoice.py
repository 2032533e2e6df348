"""Which kernel a command runs on, decided by name without importing one (no numpy: `canfdi
--version` answers in milliseconds). canfdi.core.kernel holds the kernels themselves.

>>> choose("python", env={})
'python'
>>> choose(None, env={"CANFDI_KERNEL": "python"})
'python'
"""

from __future__ import annotations

import importlib.util
import os
from collections.abc import Mapping

__all__ = ["ENV", "NAMES", "KernelError", "built", "choose", "version_line"]

ENV = "CANFDI_KERNEL"
NAMES = ("c", "python")


class KernelError(ValueError):
    """A kernel name that is not one, or one not built in this install.

    Examples
    --------
    >>> try:
    ...     choose("gpu", env={})
    ... except KernelError as exc:
    ...     print(exc)
    kernel: expected one of c, python, got 'gpu'
    """


def built() -> list[str]:
    """The kernels this install has: python always, c where the extension was built."""
    return sorted(n for n in NAMES if n == "python"
                  or importlib.util.find_spec("canfdi._ckernel") is not None)


def choose(choice: str | None = None, env: Mapping[str, str] | None = None) -> str:
    """The kernel's name: ``choice`` (a --kernel), else CANFDI_KERNEL, else c where built,
    else python; KernelError for a name that is none, or one not built here."""
    env = os.environ if env is None else env
    have = built()
    name = choice or env.get(ENV) or ("c" if "c" in have else "python")
    if name not in NAMES:
        raise KernelError(f"kernel: expected one of {', '.join(NAMES)}, got {name!r}")
    if name not in have:
        raise KernelError(f"kernel {name}: not built in this install (no C compiler when "
                          f"canfdi was installed); use --kernel python")
    return name


def version_line() -> str:
    """``kernel: NAME (built: ...)``, what `canfdi --version` says of the kernels."""
    try:
        name = choose()
    except KernelError as exc:
        return f"kernel: none ({exc})"
    return f"kernel: {name} (built: {', '.join(built())})"
