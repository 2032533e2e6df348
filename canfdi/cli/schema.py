"""`canfdi schema`: the config's JSON Schema, for editors that complete and check configs."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from canfdi.cli.common import write_text
from canfdi.config import config_schema

HELP = """\
Write the JSON Schema (draft 2020-12) of a monitor config: every section and key, its type,
bounds, choices and default, made from the same tables the config reader checks with (and each
registered method's own section). What a schema cannot say is the reader's alone: sizes that
must match the model, names that must be in the DBC, a node-id template's arithmetic; run
`canfdi design CONFIG` for those.

Editors that speak the YAML language server (VS Code's YAML extension, Neovim, Helix, ...)
complete and check a config whose first line points at the schema:

  # yaml-language-server: $schema=canfdi-config.schema.json

as the configs in deploy/config/ do (their schema file is written by this command).

Exit status: 0 written, 1 the output could not be written."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("schema", help="write the config's JSON Schema (for editors)",
                       description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("-o", "--output", type=Path, metavar="FILE",
                   help="write to FILE (default: stdout)")


def text() -> str:
    """The schema as written: indented, keys in the tables' order, one newline at the end."""
    return json.dumps(config_schema(), indent=2, ensure_ascii=False) + "\n"


def run(args: argparse.Namespace) -> int:
    failed = write_text("schema", text(), args.output)
    if failed is not None:
        return failed
    if args.output is not None:
        print(f"wrote {args.output}", file=sys.stderr)
    return 0
