"""Reading some topics of an MCAP through its MessageIndex records (canfdi.io.scan): the same
messages, in the same order, with the same damage said, as the walk over every record; the walk
takes over wherever the index cannot be trusted."""

from __future__ import annotations

import random

import pytest

from canfdi.io.damage import Damage
from canfdi.io.scan import McapFile
from tests.unit.io.test_damaged_logs import write_log


@pytest.fixture(scope="module")
def log() -> tuple[bytes, list[dict]]:
    return write_log()


def _read(path, topics, indexed: bool, monkeypatch) -> tuple[list, list[str], list[int]]:
    """(messages, damage lines, where the records the walk read start)."""
    walked = []
    with monkeypatch.context() as patch:
        if not indexed:
            patch.setattr(McapFile, "_indexed_at", lambda self, *args: None)
        walk = McapFile._chunk_messages
        patch.setattr(McapFile, "_chunk_messages",
                      lambda self, *args: walked.append(args[0]) or walk(self, *args))
        damage = Damage()
        with McapFile(path, damage) as file:
            got = [(topic, t, msg["i"]) for topic, t, msg in file.messages(topics)]
    return got, damage.lines(), walked


@pytest.mark.parametrize("topics", [["/b"], ["/a", "/b"]])
def test_an_intact_file_reads_the_same_through_the_index(tmp_path, log, topics, monkeypatch):
    data, layout = log
    path = tmp_path / "log.mcap"
    path.write_bytes(data)
    got, said, walked = _read(path, topics, True, monkeypatch)
    assert got == [m for entry in layout for m in entry["messages"] if m[0] in topics]
    assert not {entry["offset"] for entry in layout} & set(walked) and not said
    assert (got, said) == _read(path, topics, False, monkeypatch)[:2]


def test_damage_reads_the_same_through_the_index_as_by_the_walk(tmp_path, log, monkeypatch):
    data, _ = log
    rng = random.Random(5)
    path = tmp_path / "bad.mcap"
    for _ in range(80):
        bad = bytearray(data)
        for _ in range(rng.randint(1, 3)):
            at = rng.randrange(8, len(bad))
            n = rng.randint(1, 40)
            bad[at: at + n] = rng.randbytes(min(n, len(bad) - at))
        path.write_bytes(bytes(bad))
        assert _read(path, ["/b"], True, monkeypatch)[:2] == \
            _read(path, ["/b"], False, monkeypatch)[:2]
