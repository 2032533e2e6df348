"""Sphinx extension: the pages that are generated from the code when the site is built, so
they cannot drift from it.

- ``_generated/cli.md``: every verb's ``--help``, from the command's own parser;
- ``_generated/config.md``: every config key from the config's JSON Schema (`canfdi schema`,
  made from the validator's tables), with the line the validator prints for a bad value,
  obtained by giving it one;
- ``_generated/topics.md``: the MCAP channels of a real log (the demo's), with their schemas as
  the log holds them;
- ``_generated/figures/`` and ``_generated/site-extra/fleet-report/``: figures.py's runs.

The pages of docs/reference/ include these files.
"""

from __future__ import annotations

import copy
import functools
import json
from pathlib import Path
from typing import Any

import figures
import yaml

REPO = Path(__file__).resolve().parents[2]


def _kind(schema: dict[str, Any]) -> str:
    if "title" in schema:
        return schema["title"]
    if "enum" in schema:
        return "one of " + ", ".join(f"`{v}`" for v in schema["enum"] if v is not None)
    if "const" in schema:
        return f"`{schema['const']}`"
    if "anyOf" in schema:
        kinds = []
        for option in schema["anyOf"]:
            kind = _kind(option)
            if kind not in kinds and kind != "null":
                kinds.append(kind)
        if "number" in kinds:  # a number PyYAML reads as text is one too
            kinds = [k for k in kinds if k != "a number as text"]
        return " or ".join(kinds)
    types = schema.get("type", "any")
    types = [t for t in (types if isinstance(types, list) else [types]) if t != "null"]
    names = {"integer": "integer", "number": "number", "string": "text", "boolean": "true/false",
             "array": "list", "object": "mapping"}
    kind = " or ".join(names.get(t, t) for t in types) or "null"
    if schema.get("pattern") and "string" in types:
        kind = "a number as text" if "[eE]" in schema["pattern"] else kind
    if "array" in types and "items" in schema:
        kind = f"list of {_kind(schema['items'])}"
    return kind


def _bounds(schema: dict[str, Any]) -> str:
    source = schema["anyOf"][0] if "anyOf" in schema and "type" in schema["anyOf"][0] else schema
    parts = []
    for key, sign in (("minimum", ">="), ("exclusiveMinimum", ">"), ("maximum", "<="),
                      ("exclusiveMaximum", "<"), ("minItems", "items >="),
                      ("maxItems", "items <=")):
        if key in source:
            parts.append(f"{sign} {source[key]:g}")
    return ", ".join(parts)


@functools.cache
def _shipped(name: str) -> dict[str, Any]:
    """A shipped config as loaded (read once per build; callers change a copy)."""
    return yaml.safe_load((REPO / "deploy" / "config" / f"{name}.yaml").read_text())


def _error(path: tuple[str, ...], schema: dict[str, Any]) -> str:
    """What the validator says of a value of the wrong type at ``path`` (it is asked)."""
    from canfdi.config import ConfigError, parse_config

    kind = schema.get("type", "")
    wrong: Any = "?"
    if "enum" in schema:
        wrong = "no_such_choice"
    elif "string" in str(kind):
        wrong = 7
    for name in ("dc_motor", "vtol_uio", "winding_machine_oe"):
        document = copy.deepcopy(_shipped(name))
        if path[0] in ("uio", "output_error") and document.get("method") != path[0]:
            continue
        node = document
        for key in path[:-1]:
            if not isinstance(node.get(key), dict):
                node[key] = {}
            node = node[key]
        node[path[-1]] = copy.deepcopy(wrong)
        try:
            parse_config(document, allow_unidentified=True)
        except ConfigError as exc:
            return str(exc) if exc.field == ".".join(path) else ""
        return ""
    return ""


def _section(lines: list[str], path: tuple[str, ...], schema: dict[str, Any]) -> None:
    rows, nested = [], []
    for key, sub in schema.get("properties", {}).items():
        where = (*path, key)
        if "properties" in sub and sub.get("additionalProperties") is False:
            nested.append((where, sub))
            continue
        default = sub.get("default")
        text = sub.get("description", "")
        required = key in schema.get("required", [])
        error = _error(where, sub) if "type" in sub or "anyOf" in sub else ""
        shown = "" if default is None else f"`{json.dumps(default)}`"
        rows.append(f"| `{key}`{' (required)' if required else ''} | {_kind(sub)} | "
                    f"{_bounds(sub)} | {shown} | {text} | {error.replace('|', '/')} |")
    lines += [f"## `{'.'.join(path)}`" if path else "## (top level)", ""]
    if rows:
        lines += ["| key | type | bounds | default | what | a bad value says |",
                  "|---|---|---|---|---|---|", *rows, ""]
    for where, sub in nested:
        _section(lines, where, sub)


def config_page() -> str:
    from canfdi.config import config_schema

    schema = config_schema()
    lines = [
        "Generated from `canfdi schema` when this site was built; the last column is what "
        "the validator prints for a value of the wrong type there (it was asked).", ""]
    _section(lines, (), schema)
    return "\n".join(lines) + "\n"


def topics_page(log: Path) -> str:
    from mcap.reader import make_reader

    with log.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    lines = [f"The channels of `{log.name}`, written by `canfdi demo -o` when this site was "
             "built (the DC motor on canfdi's bus), and each one's schema as the log holds "
             "it. A row topic's fields are the config's signal and residual names.", ""]
    for channel in sorted(summary.channels.values(), key=lambda c: c.topic):
        schema = summary.schemas[channel.schema_id]
        lines += [f"## `{channel.topic}`", "",
                  f"message encoding `{channel.message_encoding}`; schema `{schema.name}` "
                  f"(`{schema.encoding}`)", ""]
        data = schema.data.decode()
        if schema.encoding == "jsonschema":
            lines += ["```json", json.dumps(json.loads(data), indent=2), "```", ""]
        else:
            lines += ["```text", data.rstrip(), "```", ""]
    return "\n".join(lines) + "\n"


def cli_page() -> str:
    """Every verb's --help, as the installed command prints it."""
    import os

    from canfdi.cli import VERBS, build_parser

    os.environ["COLUMNS"] = "100"  # argparse wraps to the terminal's width: fix it
    parser = build_parser()
    verbs = next(a for a in parser._actions if a.dest == "verb").choices
    lines = ["## `canfdi`", "", "```text", parser.format_help().rstrip(), "```", ""]
    for name in VERBS:
        lines += [f"## `canfdi {name}`", "", "```text", verbs[name].format_help().rstrip(),
                  "```", ""]
    return "\n".join(lines) + "\n"


def _write(path: Path, text: str) -> None:
    if not path.exists() or path.read_text() != text:
        path.write_text(text)


def generate(app) -> None:
    out = Path(app.srcdir) / "_generated"
    out.mkdir(exist_ok=True)
    figures.make(out)
    _write(out / "config.md", config_page())
    _write(out / "topics.md", topics_page(out / "runs" / "demo.mcap"))
    _write(out / "cli.md", cli_page())


def setup(app) -> dict[str, Any]:
    app.connect("builder-inited", generate)
    return {"version": "1", "parallel_read_safe": True}
