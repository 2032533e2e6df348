"""The row topics as ROS 2 CDR messages (canfdi.io.cdr, the default row encoding): exact values,
names, drives, damaged messages, and Foxglove's own Python reader of ROS 2 messages in MCAP
(mcap-ros2-support) decoding every row as canfdi wrote it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from canfdi.core.records import Sample
from canfdi.io.cdr import CdrDecoder, CdrRowEncoder, check_field_names, field_names, row_definition
from canfdi.io.damage import Damage
from canfdi.io.reader import read_log, read_residuals, read_rows, read_samples
from canfdi.io.rowencodings import DEFAULT_ROW_ENCODING, ROW_ENCODINGS
from canfdi.io.schemas import TOPIC_RESIDUALS, TOPIC_SAMPLES
from canfdi.io.writer import McapRecorder

T0 = 1_700_000_000_123_456_789
INPUTS = ["V", "load:Nm"]
OUTPUTS = ["i_a", "omega r", "i_A"]
RESIDUALS = ["a:V", "s:i_a", "s:omega r"]


def _record(path: Path, rows: int = 40, drive: str | None = None, encoding: str = "cdr"
            ) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(7)
    U = rng.standard_normal((rows, 2))
    Z = rng.standard_normal((rows, 3)) * 10.0 ** rng.integers(-300, 300, (rows, 3))
    Z[3, 1], Z[4, 2], Z[5, 0] = np.nan, np.inf, -0.0
    R = rng.standard_normal((rows, 3, 3))
    R[6, 1, 2] = -np.inf
    k, t = np.arange(rows), T0 + np.arange(rows) * 1000
    with McapRecorder(path, block_samples=16, row_encoding=encoding) as rec:
        rec.write_samples(k, t, U, Z, k % 3, INPUTS, OUTPUTS, drive=drive)
        rec.write_residual_rows(k, t, RESIDUALS, R[:, 0], R[:, 1], R[:, 2], drive=drive)
    return k, t, U, Z, R


def test_cdr_is_the_default_and_the_registry_names_both() -> None:
    assert DEFAULT_ROW_ENCODING == "cdr" and set(ROW_ENCODINGS) == {"cdr", "json"}
    with pytest.raises(ValueError, match="unknown row encoding 'xml' \\(known: cdr, json\\)"):
        McapRecorder(None, row_encoding="xml")


def test_rows_read_back_exactly_every_float_kept(tmp_path: Path) -> None:
    """Unlike JSON, CDR keeps inf, NaN and -0.0 as written."""
    path = tmp_path / "run.mcap"
    k, t, U, Z, R = _record(path)
    samples = read_samples(path)
    assert samples.input_names == INPUTS and samples.output_names == OUTPUTS
    assert samples.k.tolist() == k.tolist() and samples.t_ns.tolist() == t.tolist()
    assert samples.gap.tolist() == (k % 3).tolist()
    np.testing.assert_array_equal(samples.U, U)
    np.testing.assert_array_equal(samples.Z, Z)
    assert np.signbit(samples.Z[5, 0]) and samples.Z[4, 2] == np.inf
    k2, t2, names, r, rn, stat = read_residuals(path)
    assert names == RESIDUALS and k2.tolist() == k.tolist() and t2.tolist() == t.tolist()
    for got, want in zip((r, rn, stat), (R[:, 0], R[:, 1], R[:, 2]), strict=True):
        np.testing.assert_array_equal(got, want)


def test_json_and_cdr_logs_read_back_the_same_rows(tmp_path: Path) -> None:
    _record(tmp_path / "cdr.mcap", encoding="cdr")
    _record(tmp_path / "json.mcap", encoding="json")
    for topic in (TOPIC_SAMPLES, TOPIC_RESIDUALS):
        a, b = read_rows(tmp_path / "cdr.mcap", topic), read_rows(tmp_path / "json.mcap", topic)
        assert a.names == b.names and a.t_ns.tolist() == b.t_ns.tolist()
        for key, column in a.columns.items():
            finite = np.where(np.isfinite(column), column, np.nan)  # JSON writes null for inf
            np.testing.assert_array_equal(finite, b.columns[key])


def test_foxglove_ros2_reader_decodes_every_row(tmp_path: Path) -> None:
    """mcap-ros2-support (Foxglove's) parses the schemas and decodes every message to the values
    canfdi wrote, its fields the ROS 2 names of canfdi's."""
    from mcap_ros2.decoder import DecoderFactory

    path = tmp_path / "run.mcap"
    k, t, U, Z, R = _record(path, drive="left")
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        got: dict[str, list] = {TOPIC_SAMPLES: [], TOPIC_RESIDUALS: []}
        for schema, channel, message, decoded in reader.iter_decoded_messages(
                topics=list(got)):
            assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
            got[channel.topic].append((message.log_time, decoded))
    assert [m for m, _ in got[TOPIC_SAMPLES]] == t.tolist()
    inputs, outputs = field_names(INPUTS), field_names(OUTPUTS)
    assert outputs == ["i_a", "omega_r", "i_a_2"]
    for i, (_, row) in enumerate(got[TOPIC_SAMPLES]):
        assert (row.t_ns, row.k, row.gap, row.drive) == (t[i], k[i], k[i] % 3, "left")
        np.testing.assert_array_equal([getattr(row.u, f) for f in inputs], U[i])
        np.testing.assert_array_equal([getattr(row.z, f) for f in outputs], Z[i])
    names = field_names(RESIDUALS)
    for i, (_, row) in enumerate(got[TOPIC_RESIDUALS]):
        for j, group in enumerate(("r", "normalized", "statistic")):
            np.testing.assert_array_equal([getattr(getattr(row, group), f) for f in names],
                                          R[i, j])


def test_each_drive_and_name_list_has_its_own_channel_reused(tmp_path: Path) -> None:
    """Two drives' rows alternate between two exact schemas: two channels, each registered
    once, each drive's rows read back with its own names."""
    path = tmp_path / "run.mcap"
    with McapRecorder(path) as rec:
        for i in range(6):
            drive = ("left", "right")[i % 2]
            outputs = ["x"] if drive == "left" else ["x", "y"]
            rec.write_sample(Sample(k=i, timestamp_ns=T0 + i, u=np.array([1.0 * i]),
                                    z=np.arange(len(outputs)) + 10.0 * i, gap=0),
                             ["v"], outputs, drive=drive)
            rec.flush()
    left = read_samples(path, drive="left")
    right = read_samples(path, drive="right")
    assert left.k.tolist() == [0, 2, 4] and left.output_names == ["x"]
    assert right.k.tolist() == [1, 3, 5] and right.output_names == ["x", "y"]
    np.testing.assert_array_equal(right.Z, [[10.0, 11.0], [30.0, 31.0], [50.0, 51.0]])
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    channels = [c for c in summary.channels.values() if c.topic == TOPIC_SAMPLES]
    assert len(channels) == 2
    texts = sorted(summary.schemas[c.schema_id].data.decode() for c in channels)
    assert "float64 y  # canfdi: \"y\"" in texts[1] and "float64 y" not in texts[0]


def test_a_damaged_row_is_counted_not_raised(tmp_path: Path) -> None:
    """A message cut short (its record still framed) is a bad message, the others are read."""
    from mcap.writer import Writer

    text = row_definition("canfdi/msg/Sample", ["k", "gap"],
                          [("u", ["v"], "input"), ("z", ["w"], "output")], False)
    good = CdrRowEncoder(2, 2).encode(np.array([T0]), np.array([[1, 0]]),
                                      np.array([[1.0, 2.0]]))[0].tobytes()
    path = tmp_path / "damaged.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start()
        schema = writer.register_schema("canfdi/msg/Sample", "ros2msg", text.encode())
        channel = writer.register_channel(TOPIC_SAMPLES, "cdr", schema)
        for i, data in enumerate((good, good[:20], b"\x01\x00\x00\x00" + good[4:], good)):
            writer.add_message(channel, T0 + i, data, T0 + i)
        writer.finish()
    damage = Damage()
    samples = read_samples(path, damage=damage)
    assert samples.t_ns.size == 2 and samples.Z.tolist() == [[2.0], [2.0]]
    (found,) = damage.files.values()
    assert len(found.bad_messages) == 2  # cut short; big-endian (not written)


def test_the_decoder_reads_nested_arrays_and_strings() -> None:
    """Beyond canfdi's rows: arrays (fixed, bounded, unbounded), strings between fields,
    constants and defaults skipped, a type named with /msg/."""
    text = "\n".join([
        "int8 A=3", "uint8 flag", "string name", "float64[2] pair", "int32[] list",
        "pkg/Inner[<=2] inner", "uint16 tail 7", "=" * 80, "MSG: pkg/msg/Inner",
        "float32 x", "bool ok"])
    body = (b"\x05" + b"\0\0\0" + b"\x03\0\0\0ab\0" + b"\0" * 5 + np.array(
        [1.5, -2.0]).tobytes() + b"\x02\0\0\0" + np.array([7, -8], "<i4").tobytes()
        + b"\x01\0\0\0" + np.array([0.25], "<f4").tobytes() + b"\x01" + b"\0" + b"\x09\0")
    got = CdrDecoder(text)(b"\x00\x01\x00\x00" + body)
    assert got == {"flag": 5, "name": "ab", "pair": [1.5, -2.0], "list": [7, -8],
                   "inner": [{"x": 0.25, "ok": True}], "tail": 9}
    with pytest.raises(ValueError, match="shorter than its definition"):
        CdrDecoder(text)(b"\x00\x01\x00\x00" + body[:30])
    with pytest.raises(ValueError, match="without the type"):
        CdrDecoder("other/Missing m")
    with pytest.raises(ValueError, match="wide strings"):
        CdrDecoder("wstring w")


@settings(max_examples=200, deadline=None)
@given(st.lists(st.text(min_size=0, max_size=8), min_size=1, max_size=12, unique=True))
def test_field_names_are_ros2_names_unique_and_read_back(names: list[str]) -> None:
    fields = field_names(names)
    assert check_field_names(fields) and len(set(fields)) == len(fields)
    assert field_names(names) == fields  # a rule, not a state
    text = row_definition("t/msg/T", ["k"], [("g", names, "v")], drive=True)
    values = np.arange(len(names), dtype=float)
    data = CdrRowEncoder(1, len(names), "d").encode(np.array([5]), np.array([[2]]),
                                                    values[None])
    decoded = CdrDecoder(text)(data[0].tobytes())
    assert decoded == {"t_ns": 5, "k": 2, "g": dict(zip(names, values.tolist(), strict=True)),
                       "drive": "d"}
    assert all(json.dumps(n) in text for n in names)


def test_read_log_gives_rows_by_their_canfdi_names(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    _record(path, rows=8)
    (first, *_) = [m for topic, _, m in read_log(path, topics=[TOPIC_RESIDUALS])]
    assert list(first) == ["t_ns", "k", "r", "normalized", "statistic"]
    assert list(first["r"]) == RESIDUALS
