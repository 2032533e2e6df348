"""canfdi's MCAP logs opened by readers no one here wrote.

- pymcap-cli's ``doctor`` (PyPI): the MCAP container spec (CRCs, indexes, summary groups) finds
  no error and no warning in any kind of canfdi log;
- Foxglove's MCAP library for JavaScript (@mcap/core, under node): streaming and indexed
  readers, CRCs validated, the same messages per topic as canfdi's reader; the data section
  CRC it reports matches the file's bytes;
- Lichtblick's JSON-schema parser (the last open-source Foxglove Studio's lineage) accepts every
  JSON channel's schema and post-processes every message (rows recorded as JSON too, with
  ``row_encoding="json"``); the log's foxglove.Log schema is Foxglove's own (@foxglove/schemas);
- Foxglove's ROS 2 libraries (@foxglove/rosmsg, @foxglove/rosmsg2-serialization) parse the row
  topics' ros2msg schemas as Foxglove does and decode every CDR row, to the values canfdi's own
  reader gives;
- mcap's Python reader, CRCs validated, reads every message of every segment.

The node tools (tests/node/package.json, locked) are installed on first use with npm; the node
tests are skipped, with the reason, where node or npm is missing.
"""

from __future__ import annotations

import collections
import json
import shutil
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
from canfdi.configs import CONFIG_DIR
from mcap.reader import make_reader

from canfdi.bus.frames import FrameBlock
from canfdi.io.cdr import field_names
from canfdi.io.reader import read_log, read_residuals, read_samples
from canfdi.io.schemas import FOXGLOVE_LOG_SCHEMA
from canfdi.io.segments import log_segments
from canfdi.io.writer import McapRecorder
from tests.cli import canfdi_main as main

NODE_DIR = Path(__file__).resolve().parents[1] / "node"
T0 = 1_800_000_000_000_000_000
ROW_TOPICS = ("/canfdi/samples", "/canfdi/residuals")


def _encodings(path: Path) -> dict[str, tuple[str, str]]:
    """Each topic's (schema encoding, message encoding)."""
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    return {c.topic: (summary.schemas[c.schema_id].encoding, c.message_encoding)
            for c in summary.channels.values()}


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> dict[str, Path]:
    """One log of every kind canfdi writes."""
    d = tmp_path_factory.mktemp("logs")
    out = {}
    out["demo"] = d / "demo.mcap"
    assert main(["demo", "--no-live", "--json", "-o", str(out["demo"])]) == 0
    out["two_drives"] = d / "two.mcap"
    assert main(["demo", "--no-live", "--json", "--scenario", "dc_motor_two_drives_cia402",
                 "-o", str(out["two_drives"])]) == 0
    out["demo_json"] = d / "demo_json.mcap"
    # The demo with its rows in JSON (the layout of logs before CDR rows), as a user asks
    # for it: the config's recording.row_encoding.
    shipped = (CONFIG_DIR / "dc_motor.yaml").read_text()
    assert "\n  rotate_minutes: 60\n" in shipped
    json_rows = d / "dc_motor_json_rows.yaml"
    json_rows.write_text(shipped.replace("\n  rotate_minutes: 60\n",
                                         "\n  rotate_minutes: 60\n  row_encoding: json\n"))
    assert main(["demo", "--no-live", "--json", "--config", str(json_rows),
                 "-o", str(out["demo_json"])]) == 0
    for kind, rows in (("demo", ("ros2msg", "cdr")), ("two_drives", ("ros2msg", "cdr")),
                       ("demo_json", ("jsonschema", "json"))):
        encodings = _encodings(out[kind])
        assert [encodings[topic] for topic in ROW_TOPICS] == [rows, rows], kind
    out["empty"] = d / "empty.mcap"
    McapRecorder(out["empty"]).close()
    out["rotated"] = d / "rotated.mcap"
    n = 20000
    block = FrameBlock(T0 + np.arange(n) * 100_000, np.arange(n) % 0x7FF, np.full(n, 8),
                       np.zeros(n, np.uint8), np.random.default_rng(1).integers(
                           0, 256, (n, 8)).astype(np.uint8))
    with McapRecorder(out["rotated"], rotate_bytes=100_000, chunk_size=50_000) as rec:
        for part in range(0, n, 1000):
            rec.write_frames(block.slice(part, part + 1000), "ok")
            rec.flush()
    assert len(log_segments(out["rotated"])) > 2
    return out


def _files(logs: dict[str, Path]) -> list[tuple[str, Path]]:
    return [(f"{name}:{p.name}", p) for name, first in logs.items() for p in log_segments(first)]


KINDS = ["demo", "two_drives", "demo_json", "empty", "rotated"]


@pytest.mark.skipif(shutil.which("pymcap-cli") is None
                    and not (Path(sys.executable).parent / "pymcap-cli").exists(),
                    reason="pymcap-cli is not installed (the test extra installs it)")
@pytest.mark.parametrize("kind", KINDS)
def test_pymcap_doctor_finds_no_error_or_warning(logs, kind) -> None:
    exe = Path(sys.executable).parent / "pymcap-cli"
    for segment in log_segments(logs[kind]):
        run = subprocess.run([str(exe if exe.exists() else "pymcap-cli"), "doctor", str(segment),
                              "--format", "jsonl"], capture_output=True, text=True, timeout=300)
        lines = [json.loads(line) for line in run.stdout.splitlines() if line.startswith("{")]
        (summary,) = [x for x in lines if x["type"] == "summary"]
        bad = [x for x in lines if x["type"] == "finding"
               and x["severity"] in ("error", "warning")]
        assert run.returncode == 0 and summary["errors"] == 0 and summary["warnings"] == 0, bad
        assert summary["complete"]


@pytest.mark.parametrize("kind", KINDS)
def test_mcap_python_reader_validates_every_crc(logs, kind) -> None:
    for segment in log_segments(logs[kind]):
        ours = collections.Counter(topic for topic, _, _ in read_log(segment))
        with open(segment, "rb") as f:
            reader = make_reader(f, validate_crcs=True)
            theirs = collections.Counter(c.topic for _, c, _ in reader.iter_messages())
            summary = reader.get_summary()
        assert theirs == ours
        assert summary is not None and summary.statistics.message_count == sum(ours.values())


@pytest.fixture(scope="module")
def node_tools() -> Path:
    if shutil.which("node") is None or shutil.which("npm") is None:
        pytest.skip("node and npm are not installed: the JavaScript readers cannot run")
    wanted = json.loads((NODE_DIR / "package.json").read_text())["devDependencies"]
    if not all((NODE_DIR / "node_modules" / name / "package.json").exists() for name in wanted):
        run = subprocess.run(["npm", "ci", "--no-audit", "--no-fund", "--ignore-scripts"],
                             cwd=NODE_DIR, capture_output=True, text=True, timeout=600)
        if run.returncode != 0:
            pytest.skip(f"npm ci in {NODE_DIR} failed: {run.stderr.strip()[-300:]}")
    return NODE_DIR / "check.js"


def node_check(script: Path, path: Path, *options: str) -> dict:
    run = subprocess.run(["node", str(script), *options, str(path)], capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout)


def _plain(value):
    """A value as check.js prints it: an int beyond JavaScript's exact integers as a decimal
    string, NaN and the infinities as "NaN", "Infinity", "-Infinity"."""
    if isinstance(value, dict):
        return {key: _plain(v) for key, v in value.items()}
    if isinstance(value, list):
        return [_plain(v) for v in value]
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) > 2**53 - 1:
        return str(value)
    if isinstance(value, float) and not np.isfinite(value):
        return "NaN" if np.isnan(value) else "Infinity" if value > 0 else "-Infinity"
    return value


def _as_ros2(message: dict) -> dict:
    """A row of canfdi's reader (canfdi's names) with the ROS 2 field names of its schema."""
    return _plain({key: dict(zip(field_names(list(value)), value.values(), strict=True))
                   if isinstance(value, dict) else value for key, value in message.items()})


@pytest.mark.parametrize("kind", ["demo", "two_drives", "demo_json", "rotated"])
def test_foxglove_mcap_library_and_lichtblick_schema_parser(logs, kind, node_tools) -> None:
    for segment in log_segments(logs[kind]):
        got = node_check(node_tools, segment)
        assert got["errors"] == []
        ours = dict(collections.Counter(topic for topic, _, _ in read_log(segment)))
        assert got["stream"] == ours and got["indexed"] == ours
        data = segment.read_bytes()
        # DataEnd (13 bytes) closes the data section; its CRC covers every byte before it.
        assert got["dataSectionCrc"] == zlib.crc32(data[: got["summaryStart"] - 13]) != 0
        assert got["chunkIndexes"] > 0
    assert got["foxgloveLog"] == FOXGLOVE_LOG_SCHEMA


def test_every_signal_is_a_plottable_field_for_the_parser(logs, node_tools) -> None:
    """Rows in JSON (row_encoding="json"): Lichtblick's parser makes each group of named numbers
    a type whose fields are canfdi's names."""
    got = node_check(node_tools, logs["demo_json"])
    types = {topic: schema["types"] for topic, schema in got["schemas"].items()}
    assert types["/canfdi/samples"]["canfdi.Sample.z"] == ["i_f", "i_a", "i_f_plus_i_a",
                                                           "omega_r"]
    assert types["/canfdi/samples"]["canfdi.Sample.u"] == ["V"]
    assert "s:i_a" in types["/canfdi/residuals"]["canfdi.Residuals.statistic"]
    assert got["schemas"]["/canfdi/log"]["name"] == "foxglove.Log"
    assert set(got["schemas"]) == {"/can/frames", "/canfdi/samples", "/canfdi/residuals",
                                   "/canfdi/events", "/canfdi/log", "/canfdi/estimates",
                                   "/canfdi/status"}
    assert {schema["encoding"] for schema in got["schemas"].values()} == {"jsonschema"}
    assert "canfdi.Estimates.estimates" in types["/canfdi/estimates"]
    assert got["ros2"] == []


def test_foxglove_ros2_libraries_parse_the_row_schemas(logs, node_tools) -> None:
    """Rows in CDR (the default): @foxglove/rosmsg finds each row type's fields, a ROS 2 field
    per canfdi name; the other topics stay JSON for Lichtblick's parser."""
    got = node_check(node_tools, logs["demo"])
    assert got["errors"] == []
    samples = read_samples(logs["demo"])
    residuals = read_residuals(logs["demo"])
    inputs, outputs = field_names(samples.input_names), field_names(samples.output_names)
    assert outputs == ["i_f", "i_a", "i_f_plus_i_a", "omega_r"] and inputs == ["v"]
    by_topic = {channel["topic"]: channel for channel in got["ros2"]}
    assert set(by_topic) == set(ROW_TOPICS) and len(got["ros2"]) == 2
    sample = by_topic["/canfdi/samples"]
    assert sample["schema"] == "canfdi/msg/Sample"
    assert sample["fields"] == {
        "canfdi/msg/Sample": [["t_ns", "int64"], ["k", "int64"], ["gap", "int64"],
                              ["u", "canfdi/SampleInput"], ["z", "canfdi/SampleOutput"],
                              ["drive", "string"]],
        "canfdi/SampleInput": [[name, "float64"] for name in inputs],
        "canfdi/SampleOutput": [[name, "float64"] for name in outputs],
    }
    names = field_names(residuals.names)
    assert "s_i_a" in names and "a_v" in names
    residual = by_topic["/canfdi/residuals"]
    assert residual["schema"] == "canfdi/msg/Residuals"
    assert residual["fields"] == {
        "canfdi/msg/Residuals": [["t_ns", "int64"], ["k", "int64"],
                                 ["r", "canfdi/ResidualsResidual"],
                                 ["normalized", "canfdi/ResidualsResidual"],
                                 ["statistic", "canfdi/ResidualsResidual"], ["drive", "string"]],
        "canfdi/ResidualsResidual": [[name, "float64"] for name in names],
    }
    for topic, channel in by_topic.items():
        assert got["schemas"][topic]["encoding"] == "ros2msg"
        assert channel["messages"] == got["stream"][topic] > 0
    assert {schema["encoding"] for topic, schema in got["schemas"].items()
            if topic not in ROW_TOPICS} == {"jsonschema"}
    # The first row as Foxglove decodes it is canfdi's arrays' first row.
    first = sample["first"]
    assert first["t_ns"] == str(samples.t_ns[0]) and first["k"] == samples.k[0] == 0
    assert first["gap"] == samples.gap[0]
    assert first["u"] == _plain(dict(zip(inputs, samples.U[0].tolist(), strict=True)))
    assert first["z"] == _plain(dict(zip(outputs, samples.Z[0].tolist(), strict=True)))
    first = residual["first"]
    assert first["t_ns"] == str(residuals.t_ns[0]) and first["k"] == residuals.k[0]
    for key, values in (("r", residuals.R), ("normalized", residuals.Rn),
                        ("statistic", residuals.stat)):
        assert first[key] == _plain(dict(zip(names, values[0].tolist(), strict=True)))


@pytest.mark.parametrize("kind", ["demo", "two_drives"])
def test_foxglove_decodes_every_row_as_canfdi_reads_it(logs, kind, node_tools) -> None:
    """Every CDR row @foxglove/rosmsg2-serialization decodes (the whole message read, no byte
    left) holds the values canfdi's reader gives for it, NaN included."""
    got = node_check(node_tools, logs[kind], "--rows")
    assert got["errors"] == []
    for topic in ROW_TOPICS:
        ours = [_as_ros2(message) for _, _, message in read_log(logs[kind], [topic])]
        assert len(ours) > 1000
        assert got["rows"][topic] == ours
    drives = {row["drive"] for topic in ROW_TOPICS for row in got["rows"][topic]}
    assert drives == ({"left", "right"} if kind == "two_drives" else {"dc_motor"})


def test_the_parser_rejects_what_issue_17_found(tmp_path, node_tools) -> None:
    """The vendored parser is live: the old events schema (a type union) fails in it."""
    from mcap.writer import Writer

    path = tmp_path / "old.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        s = w.register_schema("old", "jsonschema", json.dumps(
            {"type": "object", "properties": {"target": {"type": ["string", "null"]}}}).encode())
        c = w.register_channel("/old/events", "json", s)
        w.add_message(c, T0, b'{"target": null}', T0)
        w.finish()
    got = node_check(node_tools, path)
    assert got["errors"] == ['/old/events: Unsupported type ["string","null"] for target']


def test_the_ros2_libraries_reject_what_does_not_fit(tmp_path, node_tools) -> None:
    """Foxglove's ROS 2 libraries are live: a type not defined, a message shorter than its
    definition and one longer are each an error."""
    from mcap.writer import Writer

    path = tmp_path / "bad.mcap"
    t_ns = b"\x00\x01\x00\x00" + T0.to_bytes(8, "little")
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        for topic, definition, data in (
                ("/missing", b"int64 t_ns\ncanfdi/Nowhere x\n", t_ns),
                ("/short", b"int64 t_ns\nfloat64 x\n", t_ns + bytes(4)),
                ("/long", b"int64 t_ns\n", t_ns + bytes(8))):
            s = w.register_schema(f"canfdi/msg{topic}", "ros2msg", definition)
            w.add_message(w.register_channel(topic, "cdr", s), T0, data, T0)
        w.finish()
    got = node_check(node_tools, path)
    missing, short, long = got["errors"]
    assert missing == ("/missing: Expected 1 top level type definition for 'canfdi/Nowhere' "
                       "but found 0")
    assert short.startswith(f"/short: message at {T0}: ")  # the DataView's RangeError
    assert long == f"/long: message at {T0}: 12 of 20 bytes read"
    assert [(c["topic"], c["messages"]) for c in got["ros2"]] == [("/short", 0), ("/long", 0)]
