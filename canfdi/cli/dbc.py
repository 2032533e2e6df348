"""`canfdi dbc --config FILE [-o OUT.dbc] [--merge]`: the DBC of the frames a config sends."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from canfdi.cli.common import write_text

HELP = """\
Write the DBC of the monitor's own frames (FDI_FAULT, FDI_ESTIMATE, FDI_STATUS, FDI_RESIDUAL)
as this config sends them: the layout of its monitor DBC (bus.monitor.dbc, default the shipped
canfdi_monitor.dbc) at the config's IDs (bus.monitor.base or bus.monitor.ids), each message's
comment naming its E2E profile (bus.monitor.e2e). With --merge, the drives' DBC (bus.dbc) with
the monitor's messages and node added: one file that cantools, SavvyCAN or a bus analyser
decode the whole bus with. A config whose model is still to identify will do: only its bus:
section is read.

Exit status: 0 written (to stdout without -o), 2 a bad config, or a message of the drives'
DBC at a monitor ID (--merge; named), or an output that cannot be written (one line)."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("dbc", help="the DBC of the monitor's frames as a config sends them",
                       description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--config", required=True, type=Path, metavar="FILE", help="monitor config")
    p.add_argument("-o", "--output", type=Path, metavar="OUT.dbc",
                   help="write here (default: stdout)")
    p.add_argument("--merge", action="store_true",
                   help="add the monitor's messages to the drives' DBC (bus.dbc)")


def run(args: argparse.Namespace) -> int:
    from canfdi.bus.monitorframes import monitor_database
    from canfdi.config import ConfigError, load_config

    try:
        config = load_config(args.config, allow_unidentified=True)
        database = monitor_database(config, merge=args.merge)
    except ConfigError as exc:
        print(f"canfdi dbc: config error: {exc}", file=sys.stderr)
        return 2
    failed = write_text("dbc", database.as_dbc_string(), args.output, status=2)
    if failed is not None:
        return failed
    if args.output is not None:
        print(f"canfdi dbc: {len(database.messages)} messages written to {args.output}",
              file=sys.stderr)
    return 0
