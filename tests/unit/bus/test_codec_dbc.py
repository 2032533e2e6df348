"""Every message of public DBC files decodes and encodes as cantools does, a block at a time.

The files are cantools' own test DBCs and a handful of vehicle DBCs from commaai/opendbc
(tests/data/dbc/*/README.md). For each message, random payloads (with valid multiplexer values
written into most rows, so that every branch is taken) are decoded by the compiled layout and
compared, row by row, with cantools ``Message.decode``: physical values as floats, exactly; raw
values exactly (integers beyond 2**53 too); a multiplexed signal present exactly where cantools
reports it, NaN elsewhere. Where cantools refuses a whole frame (a multiplexer value with no
branch, overlapping signals), the reference is each signal decoded alone by cantools, walked
down cantools' own signal tree. Then the decoded values are encoded again and cantools decodes
(and encodes) the payloads back.
"""

from __future__ import annotations

import zlib
from functools import cache
from pathlib import Path

import cantools
import numpy as np
import pytest
from cantools.database.can import Message
from cantools.database.errors import DecodeError

from canfdi.bus.codec import MessageLayout, compile_layout
from tests.unit.bus.cantools_reference import (
    alone,
    check_against_cantools,
    check_encode,
    random_payloads,
)

DATA = Path(__file__).parents[2] / "data" / "dbc"
FILES = sorted(p for p in DATA.glob("*/*") if p.suffix.lower() == ".dbc")


@cache
def _database(path: Path):
    """The database as cantools loads it: strictly if it can, else with strict=False."""
    try:
        return cantools.database.load_file(path)
    except cantools.database.UnsupportedDatabaseFormatError:
        return cantools.database.load_file(path, strict=False)


def _compilable(message: Message) -> tuple[MessageLayout | None, list[str]]:
    """The layout of the message, or of the signals that compile; and the refused names."""
    try:
        return compile_layout(message), []
    except ValueError:
        pass
    refused = []
    for sig in message.signals:
        try:
            compile_layout(message, signals=[sig.name])
        except ValueError as exc:
            assert f"{message.name}.{sig.name}" in str(exc) or message.name in str(exc)
            refused.append(sig.name)
    kept = [s.name for s in message.signals if s.name not in refused]
    return compile_layout(message, signals=kept), refused


@pytest.mark.parametrize("path", FILES, ids=[f"{p.parent.name}/{p.name}" for p in FILES])
def test_every_message_matches_cantools(path):
    db = _database(path)
    for message in db.messages:
        where = f"{path.parent.name}/{path.name}:{message.name}"
        rng = np.random.default_rng(zlib.crc32(where.encode()))
        layout, refused = _compilable(message)
        assert (layout.is_extended, layout.is_fd, layout.dlc, layout.frame_id) == (
            message.is_extended_frame, message.is_fd, message.length, message.frame_id)
        payloads = random_payloads(message, rng)
        for name in refused:
            # What we refuse, cantools cannot decode either.
            sig = message.get_signal_by_name(name)
            with pytest.raises(DecodeError):
                alone(message, sig).decode(payloads[0, : message.length].tobytes())
        check_against_cantools(message, layout, payloads, where)
        check_encode(message, layout, payloads, where)


def coverage() -> dict:
    """What the DBC set covers (for the README and the report): run this module as a script."""
    counts = {"files": 0, "messages": 0, "signals": 0, "motorola": 0, "multiplexed": 0,
              "float": 0, "over_8_bytes": 0, "extended": 0, "fd": 0, "wide_signals": 0,
              "refused_signals": [], "frames_cantools_refuses": []}
    for path in FILES:
        db = _database(path)
        counts["files"] += 1
        for message in db.messages:
            counts["messages"] += 1
            counts["signals"] += len(message.signals)
            counts["motorola"] += sum(s.byte_order == "big_endian" for s in message.signals)
            counts["multiplexed"] += sum(s.multiplexer_signal is not None
                                         for s in message.signals)
            counts["float"] += sum(s.is_float for s in message.signals)
            counts["wide_signals"] += sum(s.length > 32 for s in message.signals)
            counts["over_8_bytes"] += message.length > 8
            counts["extended"] += message.is_extended_frame
            counts["fd"] += message.is_fd
            _, refused = _compilable(message)
            counts["refused_signals"] += [f"{path.name}:{message.name}.{r}" for r in refused]
            try:
                message.decode(bytes(message.length), decode_choices=False)
            except DecodeError as exc:
                if "unpacking" in str(exc):
                    counts["frames_cantools_refuses"].append(f"{path.name}:{message.name}")
    return counts


if __name__ == "__main__":
    import json

    print(json.dumps(coverage(), indent=1))


@pytest.mark.parametrize("path", FILES, ids=[f"{p.parent.name}/{p.name}" for p in FILES])
def test_a_value_the_encoding_clips_is_saturated_and_one_step_inside_is_not(path):
    """BusMap's saturation limits (canfdi.bus.dbc._clip_limits) over every integer signal of
    the public DBCs, whatever their scale, offset and stated range: a value beyond a nonzero
    limit, encoded and decoded as a sender and the monitor do (`SignalLayout.quantize`), is
    at or past it; the value one step inside is not. (Signals over 52 bits, whose steps a
    float64 cannot tell apart, are left out.)"""
    from canfdi.bus.dbc import _clip_limits

    db = _database(path)
    for message in db.messages:
        layout, _ = _compilable(message)
        for sig in layout.signals:
            step = abs(sig.scale)
            if sig.is_float or sig.length > 52 or step == 0.0:
                continue
            lo, hi = sig.physical_limits()
            if hi - lo < 4 * step:
                continue
            clip_lo, clip_hi = _clip_limits(sig)
            for limit, clip, inward in ((lo, clip_lo, 1.0), (hi, clip_hi, -1.0)):
                if abs(limit) < step / 2:  # a limit at 0 is none
                    assert np.isinf(clip), sig.name
                    continue
                at = float(sig.quantize(np.array([limit - inward * 10 * step]))[0])
                inside = float(sig.quantize(np.array([at + inward * step]))[0])
                assert (at <= clip) if inward > 0 else (at >= clip), (sig.name, at, clip)
                assert (inside > clip) if inward > 0 else (inside < clip), (sig.name, inside)
