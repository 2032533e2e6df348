"""The `canfdi` command as a user runs it, in this process: the one test module that imports
canfdi.cli. Tests of a verb's command line (exit status, --help, printed output) go through
it; tests of what a verb computes import the library (canfdi.tools) instead."""

from __future__ import annotations

import argparse

from canfdi.cli import build_parser, main
from canfdi.cli.common import bus_request
from canfdi.tools.session import BusRequest


def canfdi_main(argv: list[str]) -> int:
    """`canfdi ARGV...`: the exit status (printing on this process's stdout and stderr;
    argparse's own errors and --help raise SystemExit as the command exits)."""
    return main(argv)


def canfdi_parser() -> argparse.ArgumentParser:
    """The `canfdi` command's argument parser, every verb's options included."""
    return build_parser()


def run_bus_request(*options: str) -> BusRequest:
    """The bus `canfdi run --config FILE OPTIONS...` asks for (python-can's options -i, -c,
    -b, --fd, --data-bitrate, --bus-kwargs), before the config or python-can's configuration
    fill in what it leaves out."""
    return bus_request(build_parser().parse_args(["run", "--config", "FILE", *options]))
