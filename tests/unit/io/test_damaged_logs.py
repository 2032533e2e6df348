"""Issue 17: canfdi.io.scan's record walker on damaged MCAP files, and the loss it reports.

The files are written with the mcap package's own Writer (a third-party reference, not
canfdi's recorder): chunks of known messages on two topics, one chunk per second of log time,
with and without the summary a finished file has. Each kind of damage is made at a known place
and the walker must read every intact chunk, in order, skip the damaged ones and say what they
held (bytes, time range, messages per topic), without raising, allocating from a damaged
length, or hanging.
"""

from __future__ import annotations

import io
import json
import re
import struct
import time
import tracemalloc

import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from canfdi.io.damage import Damage
from canfdi.io.reader import read_log, read_metadata
from canfdi.io.scan import MAGIC, McapFile, NotMcap, scan_topic

T0 = 1_700_000_000_000_000_000
SECOND = 1_000_000_000
CHUNKS = 8
PER_CHUNK = {"/a": 30, "/b": 5}  # messages of each topic in every chunk
META = {"config_yaml": "model: dc_motor\n" * 20, "truth_json": "[]"}


def write_log(finish: bool = True, data_crcs: bool = False) -> tuple[bytes, list[dict]]:
    """A log of CHUNKS chunks, one per second (flushed), and the layout of each chunk:
    {"offset", "length", "start", "end", "messages": [(topic, log_time, i)]} (offsets and
    lengths from the summary of the finished file)."""
    out = io.BytesIO()
    writer = Writer(out, chunk_size=1 << 30, compression=CompressionType.ZSTD,
                    enable_data_crcs=data_crcs)
    writer.start(profile="", library="test")
    writer.add_metadata("canfdi", META)
    schema = writer.register_schema("s", "jsonschema", b"{}")
    channels = {topic: writer.register_channel(topic, "json", schema) for topic in PER_CHUNK}
    layout = []
    i = 0
    for c in range(CHUNKS):
        messages = []
        for m in range(max(PER_CHUNK.values())):
            for topic, n in PER_CHUNK.items():
                if m < n:
                    t = T0 + c * SECOND + m * (SECOND // 40)
                    payload = json.dumps({"i": i, "pad": "x" * 40}).encode()
                    writer.add_message(channels[topic], t, payload, t)
                    messages.append((topic, t, i))
                    i += 1
        writer.flush()  # ends the chunk
        layout.append({"messages": messages})
    if finish:
        writer.finish()
    data = out.getvalue()
    complete = data if finish else write_log(True, data_crcs)[0]
    summary = make_reader(io.BytesIO(complete)).get_summary()
    for entry, index in zip(layout, summary.chunk_indexes, strict=True):
        entry.update(offset=index.chunk_start_offset, length=index.chunk_length,
                     start=index.message_start_time, end=index.message_end_time,
                     index_end=index.chunk_start_offset + index.chunk_length
                     + index.message_index_length)
    return data, layout


@pytest.fixture(scope="module")
def log() -> tuple[bytes, list[dict]]:
    return write_log()


@pytest.fixture(scope="module")
def cut_log() -> tuple[bytes, list[dict]]:
    """The same file as a killed writer leaves it: no summary, no footer."""
    return write_log(finish=False)


def read(tmp_path, data: bytes, name: str = "log.mcap") -> tuple[list, Damage, McapFile]:
    path = tmp_path / name
    path.write_bytes(data)
    damage = Damage()
    with McapFile(path, damage) as file:
        got = [(topic, t, msg["i"]) for topic, t, msg in file.messages()]
    return got, damage, file


def everything(layout: list[dict], without: set[int] = frozenset()) -> list:
    return [m for c, entry in enumerate(layout) if c not in without for m in entry["messages"]]


def only_region(damage: Damage):
    (f,) = damage.files.values()
    assert len(f.regions) == 1, f.regions
    return f, next(iter(f.regions.values()))


def counts(entry: dict) -> dict[str, int]:
    out: dict[str, int] = {}
    for topic, _, _ in entry["messages"]:
        out[topic] = out.get(topic, 0) + 1
    return out


# ------------------------------------------------------------------------------------------
# intact files
# ------------------------------------------------------------------------------------------


def test_an_intact_file_reads_as_mcaps_own_reader_reads_it(tmp_path, log):
    data, layout = log
    got, damage, file = read(tmp_path, data)
    reference = [(c.topic, m.log_time, json.loads(m.data)["i"])
                 for _, c, m in make_reader(io.BytesIO(data)).iter_messages(log_time_order=False)]
    assert got == reference == everything(layout)
    assert not damage and damage.lines() == [] and damage.as_dict() == []
    assert file.complete and not file.truncated


def test_a_killed_writers_file_reads_whole_and_is_not_damage(tmp_path, cut_log):
    data, layout = cut_log
    got, damage, file = read(tmp_path, data)
    assert got == everything(layout)
    assert not damage and file.truncated and not file.complete


# ------------------------------------------------------------------------------------------
# a damaged chunk
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("summary", [True, False], ids=["summary", "no-summary"])
def test_a_chunk_whose_crc_fails_is_skipped_and_its_loss_said(tmp_path, log, cut_log, summary):
    data, layout = log if summary else cut_log
    entry = layout[3]
    crc_at = entry["offset"] + 9 + 24  # start, end, uncompressed size, then the CRC
    bad = bytearray(data)
    bad[crc_at] ^= 0x01
    got, damage, _ = read(tmp_path, bytes(bad))
    assert got == everything(layout, {3})
    _, region = only_region(damage)
    assert (region.start, region.end) == (entry["offset"], entry["offset"] + entry["length"])
    assert region.chunks == 1 and "CRC" in region.reason
    assert region.time_range() == (entry["start"], entry["end"])
    assert region.messages == counts(entry) and region.indexed  # from its MessageIndex records
    line = damage.lines()[0]
    assert re.fullmatch(
        rf".*log\.mcap: damaged: skipped 1 chunk \(bytes {entry['offset']}-"
        rf"{entry['offset'] + entry['length']}\), lost about 0\.7 s \(t=3\.0-3\.7 s of the "
        r"log\), 30 /a, 5 /b messages; the rest was read", line), line


def test_garbage_inside_the_compressed_data_fails_the_chunk(tmp_path, log):
    data, layout = log
    entry = layout[5]
    bad = bytearray(data)
    middle = entry["offset"] + entry["length"] // 2
    bad[middle : middle + 16] = bytes(range(1, 17))
    got, damage, _ = read(tmp_path, bytes(bad))
    assert got == everything(layout, {5})
    _, region = only_region(damage)
    assert region.start == entry["offset"] and region.chunks == 1
    assert region.messages == counts(entry)


def test_a_chunk_declaring_a_huge_size_allocates_nothing(tmp_path, log):
    data, layout = log
    entry = layout[2]
    bad = bytearray(data)
    # Uncompressed size 2**62, and the record length 2**63: neither may be allocated.
    struct.pack_into("<Q", bad, entry["offset"] + 9 + 16, 1 << 62)
    bad2 = bytearray(data)
    struct.pack_into("<Q", bad2, entry["offset"] + 1, 1 << 63)
    for damaged, reason in ((bad, "declaring"), (bad2, "")):
        tracemalloc.start()
        began = time.perf_counter()
        got, damage, _ = read(tmp_path, bytes(damaged))
        elapsed = time.perf_counter() - began
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert got == everything(layout, {2})
        assert peak < 8 << 20 and elapsed < 5
        _, region = only_region(damage)
        assert region.start == entry["offset"] and reason in region.reason


def test_a_zstd_frame_disagreeing_with_the_chunk_size_is_damage(tmp_path, log):
    data, layout = log
    entry = layout[1]
    bad = bytearray(data)
    # The zstd frame header's content size field (single segment: right after the 6 bytes
    # of magic and descriptor) made larger than the chunk says.
    compressed = entry["offset"] + 9 + 28 + 4 + 4 + 8
    assert bytes(bad[compressed : compressed + 4]) == b"\x28\xb5\x2f\xfd"
    bad[compressed + 6] ^= 0x40
    got, damage, _ = read(tmp_path, bytes(bad))
    assert got == everything(layout, {1})
    _, region = only_region(damage)
    assert region.start == entry["offset"]


# ------------------------------------------------------------------------------------------
# resynchronising after garbage
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("summary", [True, False], ids=["summary", "no-summary"])
def test_garbage_over_a_chunk_header_resyncs_at_the_next_chunk(tmp_path, log, cut_log, summary):
    data, layout = log if summary else cut_log
    entry = layout[4]
    bad = bytearray(data)
    bad[entry["offset"] : entry["offset"] + 12] = b"\xa5" * 12  # opcode and length gone
    got, damage, _ = read(tmp_path, bytes(bad))
    assert got == everything(layout, {4})
    f, region = only_region(damage)
    assert region.start == entry["offset"]
    # Reading resumed at the chunk's intact MessageIndex records, which count its messages.
    assert region.end == entry["offset"] + entry["length"]
    assert region.messages == counts(entry)
    first, last = region.time_range()
    if summary:  # the summary's ChunkIndex says which chunk and when
        assert region.chunks == 1 and (first, last) == (entry["start"], entry["end"])
    else:  # bounded by the intact chunks around it
        assert (first, last) == (layout[3]["end"], layout[5]["start"])
    assert f.lost_seconds() == pytest.approx((last - first) / SECOND)


@pytest.mark.parametrize("summary", [True, False], ids=["summary", "no-summary"])
def test_a_zeroed_span_over_two_chunks(tmp_path, log, cut_log, summary):
    data, layout = log if summary else cut_log
    start = layout[2]["offset"] + 100
    stop = layout[4]["offset"] - 50  # into chunk 3's MessageIndex records
    bad = data[:start] + bytes(stop - start) + data[stop:]
    got, damage, _ = read(tmp_path, bad)
    assert got == everything(layout, {2, 3})
    _, region = only_region(damage)
    assert region.start == layout[2]["offset"] and region.end <= layout[4]["offset"]
    first, last = region.time_range()
    assert first <= layout[2]["start"] and last >= layout[3]["end"] - SECOND // 4
    assert last <= layout[4]["start"] and first >= layout[1]["end"]
    if summary:
        assert region.chunks == 2 and (first, last) == (layout[2]["start"], layout[3]["end"])
    assert "lost about" in damage.lines()[0]


def test_random_bytes_at_random_places_never_raise_and_keep_the_order(tmp_path, log, cut_log):
    import random

    rng = random.Random(17)
    for data, layout in (log, cut_log):
        every = everything(layout)
        for _ in range(60):
            bad = bytearray(data)
            for _ in range(rng.randint(1, 3)):
                at = rng.randrange(8, len(bad))
                n = rng.randint(1, 300)
                bad[at : at + n] = rng.randbytes(min(n, len(bad) - at))
            got, damage, _ = read(tmp_path, bytes(bad))
            positions = [every.index(m) for m in got]
            assert positions == sorted(positions) and len(set(positions)) == len(positions)
            if len(got) < len(every):
                assert damage, "messages lost without a word"
                assert damage.lines()[0].endswith("the rest was read")


def test_every_truncation_reads_a_prefix_and_says_when_a_record_was_cut(tmp_path, cut_log):
    data, layout = cut_log
    every = everything(layout)
    ends = {entry["index_end"] for entry in layout}
    previous = 0
    for cut in [*range(0, 200), *range(200, len(data), 97), len(data)]:
        got, damage, file = read(tmp_path, data[:cut])
        assert got == every[: len(got)] and len(got) >= previous
        previous = len(got)
        assert file.truncated
        at_boundary = cut in ends or cut == layout[0]["offset"]
        if damage:
            (f,) = damage.files.values()
            assert all(r.cut for r in f.regions.values()) and not at_boundary
            assert ("cut short at byte" if cut else "empty") in damage.lines()[0]
    assert previous == len(every)


def test_a_cut_chunk_says_its_time(tmp_path, cut_log):
    data, layout = cut_log
    entry = layout[6]
    got, damage, _ = read(tmp_path, data[: entry["offset"] + entry["length"] // 2])
    assert got == everything(layout[:6])
    _, region = only_region(damage)
    assert region.cut and region.chunks == 1
    assert region.time_range() == (entry["start"], entry["end"])


# ------------------------------------------------------------------------------------------
# the magic, the header and the summary
# ------------------------------------------------------------------------------------------


def test_a_wrong_magic_before_an_mcap_header_is_damage_else_not_mcap(tmp_path, log):
    data, layout = log
    got, damage, _ = read(tmp_path, b"\x00" + data[1:])
    assert got == everything(layout)
    assert damage.files[str(tmp_path / "log.mcap")].bad_magic
    assert "magic" in damage.lines()[0]
    for other in (b"PK\x03\x04" + bytes(60), bytes(range(256)) * 8, b"x" * 9):
        path = tmp_path / "other.mcap"
        path.write_bytes(other)
        with pytest.raises(NotMcap, match="not an MCAP file"):
            McapFile(path)
        with pytest.raises(NotMcap):
            list(read_log(path))


def test_an_empty_file_or_a_part_of_the_magic_reads_nothing_and_says_so(tmp_path):
    for data, said in ((b"", "damaged: empty"), (MAGIC[:3], "cut short at byte 0 of 3")):
        got, damage, file = read(tmp_path, data)
        assert got == [] and file.truncated
        assert said in damage.lines()[0]


def test_a_damaged_header_and_metadata_are_recovered_before_the_first_chunk(tmp_path, log):
    data, layout = log
    bad = bytearray(data)
    bad[8:20] = bytes(12)  # the Header record's opcode and length
    path = tmp_path / "head.mcap"
    path.write_bytes(bytes(bad))
    damage = Damage()
    assert read_metadata(path, damage) == META  # found again after the damaged header
    got = [(t, m["i"]) for t, m in scan_topic(path, "/a", damage)]
    assert got == [(t, i) for topic, t, i in everything(layout) if topic == "/a"]
    _, region = only_region(damage)
    assert region.start == 8 and region.chunks == 0
    assert "skipped damaged bytes (bytes 8-" in damage.lines()[0]


def test_channels_lost_with_the_first_chunk_come_from_the_summary(tmp_path, log, cut_log):
    data, layout = log
    bad = bytearray(data)
    first = layout[0]["offset"]
    bad[first + 60 : first + 70] = b"\xff" * 10  # chunk 0 holds the Channel records
    got, damage, _ = read(tmp_path, bytes(bad))
    assert got == everything(layout, {0})
    # Without a summary, the topics of the channels are unknown: their messages are counted.
    data, layout = cut_log
    bad = bytearray(data)
    bad[first + 60 : first + 70] = b"\xff" * 10
    got, damage, _ = read(tmp_path, bytes(bad))
    assert got == []
    (f,) = damage.files.values()
    assert sum(f.unknown_channels.values()) == len(everything(layout, {0}))
    assert "whose definition was lost" in damage.lines()[0]


def test_a_damaged_summary_loses_no_message(tmp_path, log):
    data, layout = log
    summary_start = struct.unpack_from("<Q", data, len(data) - 8 - 20)[0]
    bad = bytearray(data)
    bad[summary_start + 5 : summary_start + 25] = b"\xee" * 20
    got, damage, _ = read(tmp_path, bytes(bad))
    assert got == everything(layout)
    _, region = only_region(damage)
    assert region.start >= summary_start and region.chunks == 0
    assert region.time_range() == (None, None)
    assert "lost" not in damage.lines()[0] and "messages" not in damage.lines()[0]


def test_the_data_section_crc_finds_damage_no_other_check_sees(tmp_path):
    data, layout = write_log(data_crcs=True)
    got, damage, _ = read(tmp_path, data)
    assert not damage
    # One character of the metadata's config text changed: every record still frames.
    at = data.index(b"model: dc_motor")
    bad = data[:at] + b"M" + data[at + 1 :]
    got, damage, _ = read(tmp_path, bad)
    assert got == everything(layout)
    (f,) = damage.files.values()
    assert f.data_crc and not f.regions
    assert "CRC does not match" in damage.lines()[0]


# ------------------------------------------------------------------------------------------
# the accumulator
# ------------------------------------------------------------------------------------------


def test_reading_a_file_twice_records_its_loss_once(tmp_path, log):
    data, layout = log
    entry = layout[3]
    bad = bytearray(data)
    bad[entry["offset"] + 9 + 24] ^= 0xFF
    path = tmp_path / "twice.mcap"
    path.write_bytes(bytes(bad))
    damage = Damage()
    for topics in (["/a"], ["/b"], None):
        list(read_log(path, topics, damage))
    _, region = only_region(damage)
    assert region.messages == counts(entry)
    (entry_json,) = damage.as_dict()
    assert entry_json["regions"][0]["messages"] == counts(entry)
    assert entry_json["regions"][0]["t_s"] == [3.0, 3.725]
    assert entry_json["lost_s"] == pytest.approx(0.725)
    assert entry_json["line"] == damage.lines()[0]
    json.dumps(entry_json)



def test_without_crcs_garbled_messages_and_records_are_counted_not_raised(tmp_path):
    out = io.BytesIO()
    writer = Writer(out, compression=CompressionType.NONE, enable_crcs=False)
    writer.start()
    channel = writer.register_channel("/a", "json", writer.register_schema("s", "jsonschema",
                                                                           b"{}"))
    for i in range(10):
        writer.add_message(channel, T0 + i, json.dumps({"i": i}).encode(), T0 + i)
    writer.flush()
    writer.add_message(channel, T0 + 10, b'{"i": 10}', T0 + 10)
    writer.finish()
    data = out.getvalue()
    at = data.index(b'{"i": 3}')
    bad = data[:at] + b"X" + data[at + 1 :]  # not JSON any more: no CRC tells
    got, damage, _ = read(tmp_path, bad)
    assert [i for _, _, i in got] == [0, 1, 2, 4, 5, 6, 7, 8, 9, 10]
    (f,) = damage.files.values()
    assert list(f.bad_messages.values()) == ["/a"]
    assert "1 messages that are not JSON" in damage.lines()[0]
    # A message record whose length runs past its chunk: the rest of the chunk is lost.
    at = data.index(b'{"i": 6}') - 22 - 8
    bad = data[:at] + struct.pack("<Q", 10**6) + data[at + 8 :]
    got, damage, _ = read(tmp_path, bad)
    assert [i for _, _, i in got] == [0, 1, 2, 3, 4, 5, 10]
    (f,) = damage.files.values()
    (region,) = f.regions.values()
    assert "do not frame" in region.reason
