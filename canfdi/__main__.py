"""The `canfdi` and `canfdi-sim` commands (and ``python -m canfdi``).

The console scripts start here rather than in canfdi.cli so that Ctrl-C at any moment, even
while the verbs' modules are still being imported, ends with one line and exit status 130
(128 + SIGINT, as a shell reports it), never a traceback. The daemon-like verbs (run, capture,
sim) catch SIGINT themselves, stop in order and return 130 too.
"""

from __future__ import annotations

import importlib
import sys

INTERRUPTED = 130


def _guarded(prog: str, module: str) -> None:
    """Exit with ``module``'s ``main()``, imported and run inside the guard: Ctrl-C is one
    line and exit 130."""
    try:
        code = importlib.import_module(module).main()
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        code = INTERRUPTED
    sys.exit(code)


NO_MF4_VERBS = ("run", "capture", "codegen")
"""Verbs that read and write no MF4 log: python-can's MF4 support is kept out of their process
(the daemon's, and `canfdi codegen`, whose goal is a few seconds)."""


def console() -> None:
    """`canfdi`: canfdi.cli.main, with Ctrl-C as one line and exit 130."""
    if sys.argv[1:2] and sys.argv[1] in NO_MF4_VERBS:
        # `import can` loads asammdf whenever it is installed (pip install 'canfdi[mf4]'),
        # and with it pandas and pyarrow: about 100 MiB and a second of start for a verb
        # that never touches an MF4 file. A None entry makes that import fail, which
        # python-can takes as "no MF4 support" (can/io/mf4.py).
        sys.modules.setdefault("asammdf", None)  # type: ignore[assignment]
    if sys.argv[1:] == ["--version"]:
        # Answered before the verbs' modules (numpy, scipy, python-can) are imported: a
        # supervisor's or a packager's version check takes milliseconds, not a second.
        from canfdi import __version__
        from canfdi.core.kernelchoice import version_line

        print(f"canfdi {__version__}\n{version_line()}")
        sys.exit(0)
    _guarded("canfdi", "canfdi.cli")


def console_sim() -> None:
    """`canfdi-sim`: canfdi.cli.sim.main, with Ctrl-C as one line and exit 130."""
    _guarded("canfdi-sim", "canfdi.cli.sim")


if __name__ == "__main__":
    console()
