"""canfdi's MCAP logs opened by readers no one here wrote.

- pymcap-cli's ``doctor`` (PyPI): the MCAP container spec (CRCs, indexes, summary groups) finds
  no error and no warning in any kind of canfdi log;
- Foxglove's MCAP library for JavaScript (@mcap/core, under node): streaming and indexed
  readers, CRCs validated, the same messages per topic as canfdi's reader; the data section
  CRC it reports matches the file's bytes;
- Lichtblick's JSON-schema parser (the last open-source Foxglove Studio's lineage) accepts every
  channel's schema and post-processes every message; the log's foxglove.Log schema is
  Foxglove's own (@foxglove/schemas);
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
from mcap.reader import make_reader

from canfdi.bus.frames import FrameBlock
from canfdi.io.reader import read_log
from canfdi.io.schemas import FOXGLOVE_LOG_SCHEMA
from canfdi.io.segments import log_segments
from canfdi.io.writer import McapRecorder
from tests.cli import canfdi_main as main

NODE_DIR = Path(__file__).resolve().parents[1] / "node"
T0 = 1_800_000_000_000_000_000


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


KINDS = ["demo", "two_drives", "empty", "rotated"]


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
    if not (NODE_DIR / "node_modules" / "@mcap" / "core").exists():
        run = subprocess.run(["npm", "ci", "--no-audit", "--no-fund", "--ignore-scripts"],
                             cwd=NODE_DIR, capture_output=True, text=True, timeout=600)
        if run.returncode != 0:
            pytest.skip(f"npm ci in {NODE_DIR} failed: {run.stderr.strip()[-300:]}")
    return NODE_DIR / "check.js"


def node_check(script: Path, path: Path) -> dict:
    run = subprocess.run(["node", str(script), str(path)], capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout)


@pytest.mark.parametrize("kind", ["demo", "two_drives", "rotated"])
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
    got = node_check(node_tools, logs["demo"])
    types = {topic: schema["types"] for topic, schema in got["schemas"].items()}
    assert types["/canfdi/samples"]["canfdi.Sample.z"] == ["i_f", "i_a", "i_f_plus_i_a",
                                                           "omega_r"]
    assert types["/canfdi/samples"]["canfdi.Sample.u"] == ["V"]
    assert "s:i_a" in types["/canfdi/residuals"]["canfdi.Residuals.statistic"]
    assert got["schemas"]["/canfdi/log"]["name"] == "foxglove.Log"
    assert set(got["schemas"]) == {"/can/frames", "/canfdi/samples", "/canfdi/residuals",
                                   "/canfdi/events", "/canfdi/log", "/canfdi/estimates",
                                   "/canfdi/status"}
    assert "canfdi.Estimates.estimates" in types["/canfdi/estimates"]


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
