"""The config's JSON Schema (`canfdi schema`, issue 44) and the validator that reads configs
agree: every shipped config passes both, what one rejects in the bad-config corpus the other
rejects (but for what a schema cannot say, listed below with why), and a value just outside
(or inside) any option's bounds, of the wrong type or under an unknown key is judged the same
by both, for every option of the schema, on a config of every method."""

from __future__ import annotations

import copy
import json
from collections.abc import Iterator
from typing import Any

import jsonschema
import pytest
import yaml

from canfdi.cli.schema import text as schema_text
from canfdi.config import (
    MAX_DOCUMENT_VALUES,
    ConfigError,
    _expanded_size,
    config_schema,
    methods,
    parse_config,
)
from tests.cli import canfdi_main as main
from tests.conftest import REPO
from tests.integration.test_bad_configs import CASES

CONFIGS = REPO / "deploy" / "config"
SCHEMA_FILE = CONFIGS / "canfdi-config.schema.json"
FIRST_LINE = "# yaml-language-server: $schema=canfdi-config.schema.json"
VALIDATOR = jsonschema.Draft202012Validator(config_schema())

# The cases of the corpus the reader rejects before a document exists (the schema never sees
# them) or that only the DBC can judge (`run` and `replay` reject them, the config is valid).
READER_ONLY = {"YAML syntax", "a binary file", "tabs in YAML", "duplicate key",
               "alias bomb in a name", "alias bomb in a matrix"}
DBC_ONLY = {"DBC: two messages of one ID", "missing DBC", "output not in the DBC"}
# What the validator rejects and no JSON Schema can: each with why.
VALIDATOR_ONLY = {
    # sizes that must match the model's (n, p, q, r): a schema has no variables
    "A wrong shape": "shape", "B wrong rows": "shape", "C wrong columns": "shape",
    "F wrong rows": "shape", "inputs count wrong": "shape", "outputs count wrong": "shape",
    "unknown inputs count wrong": "shape", "noise wrong length": "shape",
    # YAML's .nan is no JSON number: a schema's bounds cannot see it
    "A entry nan": "nan", "B entry nan": "nan", "noise nan": "nan",
    # PyYAML (YAML 1.1) reads 1e300 as text: the schema checks a number's text for its form
    # only (an editor, on YAML 1.2, reads the number and rejects it)
    "A entry 1e308": "numeric text", "C entry 1e300": "numeric text",
    # one value against another
    "min samples above max": "order", "range inverted": "order",
    "two drives one name": "order",
    # a node-id template's arithmetic, evaluated for every drive
    "100000 tildes": "template", "100000-term sum": "template", "deep brackets": "template",
    "division by zero at node 2": "template", "shift by 10^11": "template",
    "template beyond 29 bits": "template", "template calls a function": "template",
    "template unknown name": "template",
}


def _rejects(document: Any) -> ConfigError | None:
    """The validator's error, reading as `canfdi identify` does: a model may be one to learn
    (`run` then says to identify it first, in one line)."""
    try:
        parse_config(document, allow_unidentified=True)
    except ConfigError as exc:
        return exc
    return None


def test_the_schema_is_a_valid_draft_2020_12_schema():
    jsonschema.Draft202012Validator.check_schema(config_schema())
    assert set(config_schema()["properties"]["method"]["enum"]) == set(methods.names())


BUILT_IN = ("output_error", "parity", "uio")


def _built_in(schema: dict) -> dict:
    """The schema as an install without plug-in methods writes it (the suite registers a toy
    method for the conformance tests: tests/methods/conftest.py)."""
    schema = copy.deepcopy(schema)
    names = schema["properties"]["method"]["enum"]
    for name in set(names) - set(BUILT_IN):
        schema["properties"].pop(methods.get(name).section or "", None)
    schema["properties"]["method"]["enum"] = [n for n in names if n in BUILT_IN]
    return schema


def test_the_shipped_schema_file_is_what_canfdi_schema_writes(capsys, tmp_path):
    assert main(["schema"]) == 0
    printed = capsys.readouterr().out
    assert printed == schema_text()
    assert _built_in(json.loads(printed)) == json.loads(SCHEMA_FILE.read_text()), (
        "deploy/config/canfdi-config.schema.json is stale: run `canfdi schema -o "
        "deploy/config/canfdi-config.schema.json`")
    assert SCHEMA_FILE.read_text().endswith("}\n")
    assert main(["schema", "-o", str(tmp_path / "s.json")]) == 0
    assert json.loads((tmp_path / "s.json").read_text()) == config_schema()
    assert main(["schema", "-o", str(tmp_path / "no" / "s.json")]) == 1
    assert "cannot write" in capsys.readouterr().err


@pytest.mark.parametrize("path", sorted(CONFIGS.glob("*.yaml")), ids=lambda p: p.stem)
def test_every_shipped_config_points_at_the_schema_and_passes_it(path):
    text = path.read_text()
    assert text.splitlines()[0] == FIRST_LINE
    document = yaml.safe_load(text)
    errors = [f"{'.'.join(map(str, e.absolute_path))}: {e.message}"
              for e in VALIDATOR.iter_errors(document)]
    assert errors == []
    assert _rejects(document) is None


def test_schema_and_validator_agree_on_the_bad_config_corpus(tmp_path):
    assert READER_ONLY | DBC_ONLY | set(VALIDATOR_ONLY) <= set(CASES)
    disagree = {}
    for name, (text, _) in CASES.items():
        if name in READER_ONLY:
            continue
        document = yaml.safe_load(text(tmp_path) if callable(text) else text)
        assert _expanded_size(document, MAX_DOCUMENT_VALUES) <= MAX_DOCUMENT_VALUES
        by_validator = _rejects(document) is not None
        by_schema = not VALIDATOR.is_valid(document)
        assert by_validator or not by_schema, f"{name}: the schema rejects, the validator not"
        if name in DBC_ONLY:
            assert not by_validator and not by_schema, name
        elif by_validator != by_schema:
            disagree[name] = by_validator
    # Exactly the listed ones: a schema that learns one of them, or a case the schema should
    # catch and does not, fails here.
    assert disagree == dict.fromkeys(VALIDATOR_ONLY, True)


def _options(schema: dict, path: tuple[str, ...] = ()) -> Iterator[tuple[tuple, dict]]:
    """(path, schema) of every option of a section (what `Option.json_schema` wrote) and of
    every section closed to unknown keys, through the properties of objects."""
    if schema.get("additionalProperties") is False:
        yield path, schema
    for key, sub in schema.get("properties", {}).items():
        if _kind(sub) is not None:
            yield (*path, key), sub
        yield from _options(sub, (*path, key))


def _kind(schema: dict) -> str | None:
    types = schema.get("type") or schema.get("anyOf", [{}])[0].get("type")
    if isinstance(types, list) and types[1:] == ["null"]:
        return types[0]
    return None


def _mutations(schema: dict) -> Iterator[tuple[Any, bool]]:
    """(value, valid?) just inside and outside an option's bounds, and of wrong types."""
    kind = _kind(schema)
    if kind == "object":
        return
    bounds = schema.get("anyOf", [schema])[0]
    if kind in ("integer", "number"):
        yield "loud", False
        if kind == "integer":
            yield 2.5, False
        for key, step in (("minimum", -1), ("exclusiveMinimum", 0), ("maximum", 1),
                          ("exclusiveMaximum", 0)):
            if key in bounds:
                edge = bounds[key]
                nudge = max(abs(edge) * 1e-9, 1e-9) * (1 if "Min" in key else -1)
                inside = edge if step else (edge + nudge if kind == "number" else
                                            edge + (1 if "Min" in key else -1))
                outside = edge + step * max(1, abs(edge)) if step else edge
                yield (int(inside) if kind == "integer" else inside), True
                yield (int(outside) if kind == "integer" else outside), False
    elif kind == "boolean":
        yield "yes", False
        yield True, True
    elif kind == "string":
        yield 7, False
        yield "", False
        if "enum" in schema:
            yield "no_such_choice", False


CONFIG_OF_EACH = ("dc_motor", "dc_motor_two_drives_cia402", "vtol_uio", "winding_machine_oe")


@pytest.mark.parametrize("name", CONFIG_OF_EACH)
def test_every_option_is_judged_alike_by_schema_and_validator(name):
    base = yaml.safe_load((CONFIGS / f"{name}.yaml").read_text())
    section = methods.get(base.get("method", methods.DEFAULT)).section
    own = {m.section for m in map(methods.get, methods.names())} - {section}
    checked = 0
    for path, schema in _options(config_schema()):
        if path and path[0] in own:
            continue  # another method's section: not read by this config's method
        cases = [((*path, "no_such_key"), 1, False)] if schema.get(
            "additionalProperties") is False else []
        if _kind(schema) not in (None, "object"):
            cases = [(path, value, valid) for value, valid in _mutations(schema)]
        for where, value, valid in cases:
            document = copy.deepcopy(base)
            node = document
            for key in where[:-1]:
                node = node.setdefault(key, {}) if isinstance(node.get(key), dict | None) \
                    else node[key]
                if node is None:
                    break
            node[where[-1]] = value
            field = ".".join(where)
            error = _rejects(document)
            by_schema = VALIDATOR.is_valid(document)
            named = error is not None and error.field == field
            assert by_schema == valid, f"{name}: {field} = {value!r}: schema says {by_schema}"
            # a value inside its bounds may still be out of order with another (min > max)
            assert named != valid or (valid and "must be >=" in str(error)), (
                f"{name}: {field} = {value!r}: validator says {error}")
            checked += 1
    assert checked > 150
