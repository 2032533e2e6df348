"""A row topic is one JSON schema and one registration line (canfdi.io.rowtopics): a test-only
topic recorded through McapRecorder and read back by canfdi.io.reader's `read_rows` and by the
mcap package's own reader."""

from __future__ import annotations

import json
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader

from canfdi.core.records import Sample
from canfdi.io.reader import read_rows, read_samples
from canfdi.io.rowtopics import ROW_LAYOUTS, RowLayout, register_row_topic
from canfdi.io.writer import McapRecorder

TOPIC = "/test/vibration"
T0 = 1_700_000_000_000_000_000


def vibration_schema(axes: Sequence[str]) -> dict[str, Any]:
    """The test topic's JSON schema: per-axis acceleration and RMS."""
    numbers = {"type": "object", "properties": {axis: {"type": "number"} for axis in axes}}
    return {
        "title": "test.Vibration",
        "type": "object",
        "properties": {
            "timestamp": {"type": "object", "properties": {"sec": {"type": "integer"},
                                                           "nsec": {"type": "integer"}}},
            "k": {"type": "integer"},
            "peak": {"type": "integer"},
            "acc": numbers,
            "rms": numbers,
            "drive": {"type": "string"},
        },
    }


@pytest.fixture
def vibration() -> Iterator[RowLayout]:
    layout = register_row_topic(RowLayout(
        TOPIC, ("k", "peak"), (("acc", 0), ("rms", 0)), vibration_schema, ("axis",)))
    yield layout
    del ROW_LAYOUTS[TOPIC]


def stamp(ns: int) -> dict[str, int]:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def test_a_registered_topic_is_recorded_and_read_back(tmp_path: Path, vibration) -> None:
    path = tmp_path / "run.mcap"
    axes = ["x", "y"]
    tapped: list[tuple[str, str, int]] = []
    acc = np.array([[0.5, -1.0], [2.0, np.nan], [3.0, 4.0], [5.0, 6.0]])
    rms = np.array([[1.0, 1.5], [2.5, 3.5], [np.inf, 0.0], [7.0, 8.0]])
    with McapRecorder(path, block_samples=2, row_encoding="json",
                      tap=lambda topic, schema, t, data: tapped.append((topic, schema[0], t))
                      ) as rec:
        rec.write_row(TOPIC, T0, (0, 3), (acc[0], rms[0]), (axes,))
        rec.write_sample(Sample(k=0, timestamp_ns=T0, u=np.array([1.0]), z=np.array([2.0]),
                                gap=0), ["v"], ["w"])
        rec.write_row(TOPIC, T0 + 10, (1, 4), (acc[1], rms[1]), (axes,))
        rec.write_rows(TOPIC, T0 + np.array([20, 30]), (np.array([2, 3]), np.array([5, 6])),
                       (acc[2:], rms[2:]), (axes,))
        assert rec.buffered == 5
    assert rec.messages_written == 5 and rec.buffered == 0

    rows = read_rows(path, TOPIC)
    assert rows.names == (axes,)
    assert rows.t_ns.tolist() == [T0, T0 + 10, T0 + 20, T0 + 30]
    assert rows.columns["k"].tolist() == [0, 1, 2, 3]
    assert rows.columns["peak"].tolist() == [3, 4, 5, 6]
    # JSON has no NaN or inf: null, read back as NaN.
    np.testing.assert_array_equal(rows.columns["acc"], acc)
    np.testing.assert_array_equal(rows.columns["rms"], np.where(np.isfinite(rms), rms, np.nan))
    assert read_samples(path).k.tolist() == [0]  # the other row topics are as they were

    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        (channel,) = [c for c in summary.channels.values() if c.topic == TOPIC]
        schema = summary.schemas[channel.schema_id]
        assert schema.name == "test.Vibration" and schema.encoding == "jsonschema"
        assert list(json.loads(schema.data)["properties"]["acc"]["properties"]) == axes
        messages = [(m.log_time, json.loads(m.data))
                    for _, _, m in reader.iter_messages(topics=[TOPIC])]
    assert messages[0] == (T0, {"timestamp": stamp(T0), "k": 0, "peak": 3,
                                "acc": {"x": 0.5, "y": -1.0}, "rms": {"x": 1.0, "y": 1.5}})
    assert messages[1][1]["acc"] == {"x": 2.0, "y": None}
    assert messages[2][1]["rms"] == {"x": None, "y": 0.0}
    assert [t for t, _ in messages] == rows.t_ns.tolist()
    assert [(topic, name) for topic, name, _ in tapped if topic == TOPIC] == [
        (TOPIC, "test.Vibration")] * 4


def test_a_drive_and_a_wider_name_list_reach_the_schema(tmp_path: Path, vibration) -> None:
    """JSON rows: one schema naming every name (CDR's exact schemas: test_cdr_rows.py)."""
    path = tmp_path / "run.mcap"
    with McapRecorder(path, row_encoding="json") as rec:
        rec.write_row(TOPIC, T0, (0, 0), ([1.0], [2.0]), (["x"],), drive="left")
        rec.write_row(TOPIC, T0 + 1, (1, 0), ([3.0, 4.0], [5.0, 6.0]), (["x", "z"],),
                      drive="right")
    left = read_rows(path, TOPIC, drive="left")
    assert left.names == (["x"],) and left.columns["acc"].tolist() == [[1.0]]
    right = read_rows(path, TOPIC, drive="right")
    assert right.names == (["x", "z"],) and right.columns["rms"].tolist() == [[5.0, 6.0]]
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    widest = max((s for s in summary.schemas.values() if s.name == "test.Vibration"),
                 key=lambda s: s.id)
    assert list(json.loads(widest.data)["properties"]["rms"]["properties"]) == ["x", "z"]


def test_rows_that_do_not_fit_the_layout_are_refused(tmp_path: Path, vibration) -> None:
    with McapRecorder(tmp_path / "run.mcap") as rec:
        with pytest.raises(ValueError, match="widths"):
            rec.write_row(TOPIC, T0, (0, 0), ([1.0, 2.0], [1.0]), (["x", "y"],))
        with pytest.raises(ValueError, match="acc must be"):
            rec.write_rows(TOPIC, [T0], ([0], [0]), (np.ones((1, 3)), np.ones((1, 2))),
                           (["x", "y"],))
        with pytest.raises(ValueError, match="duplicate axis names"):
            rec.write_row(TOPIC, T0, (0, 0), ([1.0, 2.0], [1.0, 2.0]), (["x", "x"],))
        with pytest.raises(ValueError, match="not a row topic"):
            rec.write_row("/test/unknown", T0, (0,), ([1.0],), (["x"],))
    with pytest.raises(ValueError, match="not a row topic"):
        read_rows(tmp_path / "run.mcap", "/test/unknown")


def test_a_topic_name_is_registered_once(vibration) -> None:
    assert register_row_topic(vibration) is vibration  # the same layout again: no change
    with pytest.raises(ValueError, match="registered already"):
        register_row_topic(RowLayout(TOPIC, ("k",), (("acc", 0),), vibration_schema, ("axis",)))
