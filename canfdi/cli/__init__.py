"""The `canfdi` command: one module per verb, printing happens only here."""

from __future__ import annotations

import argparse
import os
import sys

# Tall, thin matrix products run about 10x slower with BLAS threads on 2 cores; must be set
# before numpy is imported anywhere.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from canfdi import __version__
from canfdi.cli import (
    bench,
    capture,
    dbc,
    demo,
    design,
    export,
    replay,
    report,
    run,
    schema,
    sim,
    soak,
)
from canfdi.core.kernelchoice import version_line

# isort: split
from canfdi.cli import identify  # the output_error method's model fitting (the output-error paper)

# isort: split
from canfdi.cli import evaluate  # issue 10: Monte Carlo evaluation of the diagnosis

# isort: split
from canfdi.cli import calibrate  # issue 16: the drive's noise from healthy logs

# isort: split
from canfdi.cli import fleet  # issue 18: many logs on Dask into Parquet

# isort: split
from canfdi.cli import codegen  # issue 43: the drive's monitor as a C project for its MCU

VERBS = {
    "run": run, "demo": demo, "design": design, "sim": sim, "capture": capture, "replay": replay,
    "bench": bench, "soak": soak, "export": export,
    "report": report,
    "dbc": dbc,
    "identify": identify,
    "evaluate": evaluate,
    "calibrate": calibrate,
    "fleet": fleet,
    "schema": schema,
    "codegen": codegen,
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="canfdi", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Model-based fault detection, isolation and identification on CAN buses "
                    "with fully decoupled parity equations.",
    )
    parser.add_argument("--version", action="version",
                        version=f"canfdi {__version__}\n{version_line()}")
    sub = parser.add_subparsers(dest="verb", metavar="VERB", required=True)
    for module in VERBS.values():
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return VERBS[args.verb].run(args)
    except BrokenPipeError:
        # Output piped into `head` and friends: stop quietly like other Unix tools.
        sys.stderr.close()
        return 0


if __name__ == "__main__":
    sys.exit(main())
