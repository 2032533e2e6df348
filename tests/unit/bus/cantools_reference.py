"""cantools as the reference for the codec tests: a frame's values as cantools decodes them,
and checks of a compiled layout against it (shared by test_codec.py and test_codec_dbc.py).

Where cantools refuses a whole frame (a multiplexer value with no branch, overlapping signals),
the reference is each signal decoded alone by cantools, walked down cantools' own signal tree
(``Message.signal_tree``), a multiplexer with no branch for its value ending its subtree.
"""

from __future__ import annotations

import math
import weakref

import numpy as np
from cantools.database.can import Message, Signal
from cantools.database.errors import DecodeError

from canfdi.bus.codec import MessageLayout

ROWS = 48

_alone_cache: weakref.WeakKeyDictionary[Message, dict[str, Message]] = (
    weakref.WeakKeyDictionary())


def alone(message: Message, sig: Signal) -> Message:
    """A message holding only ``sig``, not multiplexed: cantools decodes it by itself."""
    mine = _alone_cache.setdefault(message, {})
    if sig.name not in mine:
        plain = Signal(sig.name, sig.start, sig.length, sig.byte_order, sig.is_signed,
                       conversion=sig.conversion)
        mine[sig.name] = Message(frame_id=message.frame_id, name=message.name,
                                 length=message.length, signals=[plain],
                                 is_extended_frame=message.is_extended_frame, strict=False)
    return mine[sig.name]


def _set_raw(message: Message, sig: Signal, row: np.ndarray, raw: int) -> None:
    """Write ``raw`` into the bits of ``sig`` in ``row`` (cantools does the bit placing)."""
    single = alone(message, sig)
    ones = -1 if sig.is_signed else (1 << sig.length) - 1
    mask = np.frombuffer(single.encode({sig.name: ones}, scaling=False, strict=False), np.uint8)
    value = np.frombuffer(single.encode({sig.name: raw}, scaling=False, strict=False), np.uint8)
    n = message.length
    row[:n] = (row[:n] & ~mask) | value


def _bits(message: Message, sig: Signal) -> int:
    """The payload bits of ``sig``, as an integer of the payload bytes (big-endian)."""
    ones = -1 if sig.is_signed else (1 << sig.length) - 1
    try:
        mask = alone(message, sig).encode({sig.name: ones}, scaling=False, strict=False)
    except Exception:  # not in the payload: cantools cannot place it
        return 0
    return int.from_bytes(mask, "big")


def _overlapped(message: Message, layout: MessageLayout, selected: dict, n: int) -> dict:
    """signal -> (n,) bool: rows where another signal present in the row shares its bits
    (DBCs with overlapping signals: whichever is written last, the other reads it)."""
    bits = {s.name: _bits(message, message.get_signal_by_name(s.name)) for s in layout.signals}
    out = {}
    for name, mine in bits.items():
        rows = np.zeros(n, dtype=bool)
        for other, theirs in bits.items():
            if other != name and mine & theirs:
                rows |= selected.get(other, np.ones(n, dtype=bool))
        out[name] = rows
    return out


def _choose_branches(message: Message, tree: list, row: np.ndarray,
                     rng: np.random.Generator) -> None:
    """Give each multiplexer on a random path down the signal tree a value it has a branch for."""
    for node in tree:
        if isinstance(node, str):
            continue
        ((mux, branches),) = node.items()
        sig = message.get_signal_by_name(mux)
        key = int(rng.choice(sorted(branches)))
        raw = (key - sig.offset) / sig.scale
        lo, hi = ((-(1 << (sig.length - 1)), (1 << (sig.length - 1)) - 1) if sig.is_signed
                  else (0, (1 << sig.length) - 1))
        if sig.is_float or raw != round(raw) or not lo <= round(raw) <= hi:
            continue
        _set_raw(message, sig, row, round(raw))
        _choose_branches(message, branches[key], row, rng)


def random_payloads(message: Message, rng: np.random.Generator, n: int = ROWS) -> np.ndarray:
    """(n, length + 3) random payloads (3 garbage bytes beyond the message, to be ignored);
    rows 0 and 1 all zeros and all ones; in 3 rows of 4 beyond, multiplexers select a branch."""
    payloads = rng.integers(0, 256, size=(n, message.length + 3), dtype=np.uint8)
    payloads[0, : message.length] = 0
    payloads[1, : message.length] = 0xFF
    if message.is_multiplexed():
        for i in range(2, n):
            if i % 4:
                _choose_branches(message, message.signal_tree, payloads[i], rng)
    return payloads


def _walk(message: Message, tree: list, data: bytes, scaling: bool, out: dict) -> None:
    """Fill ``out`` with the signals of ``tree`` cantools would decode, each decoded alone."""
    for node in tree:
        if isinstance(node, str):
            names, branches = [node], None
        else:
            ((mux, branches),) = node.items()
            names = [mux]
        single = alone(message, message.get_signal_by_name(names[0]))
        try:
            out[names[0]] = single.decode(data, decode_choices=False, scaling=scaling)[names[0]]
        except DecodeError:
            continue  # cantools cannot decode this signal at all (it is not in the payload)
        if branches is not None:
            number = int(single.decode(data, decode_choices=False)[names[0]])
            if number in branches:
                _walk(message, branches[number], data, scaling, out)


def reference(message: Message, data: bytes, scaling: bool) -> tuple[dict, bool]:
    """cantools' decode of one frame: (signal -> value, whether the whole frame decoded).

    When cantools refuses the frame as a whole, each signal decoded alone, down the signal
    tree as cantools walks it, a multiplexer with no branch for its value ending its subtree.
    """
    try:
        return message.decode(data, decode_choices=False, scaling=scaling), True
    except DecodeError:
        out: dict = {}
        _walk(message, message.signal_tree, data, scaling, out)
        return out, False


def _same(a, b) -> bool:
    a, b = float(a), float(b)
    return a == b or (math.isnan(a) and math.isnan(b))


def check_against_cantools(message: Message, layout: MessageLayout, payloads: np.ndarray,
                           where: str) -> tuple[int, int]:
    """Compare the layout's decode, decode_raw and selected with cantools on every row.

    Returns
    -------
    (rows cantools decoded whole, rows it refused and that were compared signal by signal)
    """
    physical = layout.decode(payloads)
    raw = layout.decode_raw(payloads)
    selected = layout.selected(payloads)
    whole = refused = 0
    for i in range(payloads.shape[0]):
        data = payloads[i, : message.length].tobytes()
        ref, ok = reference(message, data, scaling=True)
        ref_raw, _ = reference(message, data, scaling=False)
        whole += ok
        refused += not ok
        for sig in layout.signals:
            name = sig.name
            ours = physical[name][i]
            here = f"{where}: {name}, row {i} ({data.hex()})"
            present = name in ref
            assert bool(selected.get(name, np.ones(i + 1, bool))[i]) == present, here
            if not present:
                assert math.isnan(ours), here
                continue
            if sig.is_float:
                assert _same(raw[name][i], ref_raw[name]), here
                assert _same(ours, ref[name]), here
                continue
            assert int(raw[name][i]) == ref_raw[name], here
            if abs(ref_raw[name]) <= 2**53:
                assert _same(ours, ref[name]), (here, ours, ref[name])
    return whole, refused


def check_encode(message: Message, layout: MessageLayout, payloads: np.ndarray,
                 where: str) -> None:
    """Encode what was decoded and have cantools decode (and encode) it back."""
    n = payloads.shape[0]
    values = layout.decode(payloads)
    encoded, _ = layout.encode(values, n)
    assert encoded.shape == (n, layout.dlc) and encoded.dtype == np.uint8
    check_against_cantools(message, layout, encoded, f"{where} (encoded)")
    # Where a signal was written and is read back, it comes back as the signal quantizes it.
    before, after = layout.selected(payloads), layout.selected(encoded)
    back, back_raw = layout.decode(encoded), layout.decode_raw(encoded)
    everywhere = np.ones(n, dtype=bool)
    overlapped = _overlapped(message, layout, after, n)
    for sig in layout.signals:
        rows = before.get(sig.name, everywhere) & after.get(sig.name, everywhere)
        rows = rows & ~overlapped[sig.name]
        want = sig.quantize(values[sig.name][rows])
        got = back[sig.name][rows]
        small = (np.ones(got.size, dtype=bool) if sig.is_float
                 else (np.abs(back_raw[sig.name][rows].astype(float)) <= 2**53)
                 & (np.abs(got) <= 2**53))  # quantize's float arithmetic is exact below
        for a, b, ok in zip(got, want, small, strict=True):
            assert not ok or _same(a, b), (where, sig.name, a, b)
    # Raw values round-trip exactly, and cantools puts the same bits where we do.
    raw = layout.decode_raw(payloads)
    exact, clipped = layout.encode_raw(raw, n)
    assert clipped == {}, (where, clipped)
    again = layout.decode_raw(exact)
    selected = layout.selected(payloads)
    overlapped = _overlapped(message, layout, selected, n)
    for name, value in raw.items():
        keep = selected.get(name, np.ones(n, bool)) & ~overlapped[name]
        if value.dtype.kind == "f":
            keep = keep & ~np.isnan(value)
        np.testing.assert_array_equal(again[name][keep], value[keep], err_msg=f"{where}: {name}")
    full_layout = len(layout.signals) == len(message.signals)
    for i in range(n):
        data = exact[i].tobytes()
        ref, ok = reference(message, data, scaling=False)
        if not ok or not full_layout or any(isinstance(v, float) and math.isnan(v)
                                            for v in ref.values()):
            continue
        assert message.encode(ref, scaling=False, strict=False) == data, (where, i)
