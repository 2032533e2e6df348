"""Precompiled DBC message layouts: many frames encoded or decoded per numpy call.

cantools' Message.encode/decode handle one frame at a time through dictionaries. A drive sends
the same few messages every period, so each message's signals are compiled once and whole blocks
of frames become integer arithmetic over numpy arrays, one pass per signal, never per frame.

Covered: everything cantools' ``Message.decode`` decodes for a DBC message (containers aside):

- Intel (little-endian) and Motorola (big-endian) signals anywhere in the payload;
- signed and unsigned integers of 1 to 64 bits (unsigned 64-bit raw values exact, as uint64);
- IEEE float16/32/64 signals, with scale and offset applied as cantools applies them;
- multiplexed signals, including extended (nested) multiplexing: a signal's value is NaN in the
  rows where its multiplexer does not select it (cantools leaves it out of the dict);
- payloads of any length (CAN FD: up to 64 bytes), 11- and 29-bit IDs.

How a signal is read, fastest first (chosen when the layout is compiled):

- *view*: a byte-aligned field of 8, 16, 32 or 64 bits is a typed numpy view of the payload
  bytes (``<i2``, ``>u4``, ``<f4``, ...), converted in one pass;
- *word*: other fields that lie within 8 consecutive bytes are two shifts of a 64-bit word of
  those bytes (little-endian for Intel, byte-swapped for Motorola); words are shared by the
  fields that use them;
- *wide*: a field of more than 56 bits spread over 9 bytes is a word and the ninth byte.

Physical values are computed as cantools computes them, so they compare equal as floats:
``raw * scale + offset`` in float64 (identity conversions skip the arithmetic), and in exact
integer arithmetic before the one rounding to float64 where scale and offset are integers (the
Python ints of cantools' ``LinearIntegerConversion``). A multiplexer selects by
``int(physical value)``, as cantools' ``decode(..., scaling=True)`` does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from canfdi.core._check import check_shape

__all__ = ["FieldPlan", "MessageLayout", "SignalLayout", "compile_layout"]

_FLOAT_BITS = (16, 32, 64)
_UINT = {16: np.uint16, 32: np.uint32, 64: np.uint64}
_VIEW_BITS = (8, 16, 32, 64)
_U64 = np.uint64


def _float_dtype(bits: int) -> np.dtype:
    return np.dtype(f"<f{bits // 8}")


def _float_at_most(value: int) -> float:
    """The largest float64 not above the integer ``value``."""
    f = float(value)
    return f if int(f) <= value else float(np.nextafter(f, -np.inf))


def _float_at_least(value: int) -> float:
    """The smallest float64 not below the integer ``value``."""
    f = float(value)
    return f if int(f) >= value else float(np.nextafter(f, np.inf))


@dataclass(frozen=True)
class SignalLayout:
    """One signal's place in the payload, its type and scaling, and its multiplexer.

    Attributes
    ----------
    name : the DBC signal name.
    start : the DBC start bit (Intel: the least significant bit, counted from bit 0 of byte 0;
        Motorola: the most significant bit, in the DBC's sawtooth numbering).
    length : bits (1..64; 16, 32 or 64 for a float).
    signed : two's-complement integer (ignored for a float).
    is_float : IEEE float of ``length`` bits.
    scale, offset : physical = raw * scale + offset.
    minimum, maximum : the DBC's physical range, or None.
    byte_order : ``"little_endian"`` (Intel) or ``"big_endian"`` (Motorola).
    is_multiplexer : other signals are selected by this signal's value.
    multiplexer_signal : the multiplexer that selects this signal, or None if always present.
    multiplexer_ids : the multiplexer values that select this signal (None when not
        multiplexed).

    Examples
    --------
    >>> sig = SignalLayout("i_a", 32, 16, True, False, 0.001, 0.0, None, None)
    >>> sig.raw_limits(), sig.physical_limits()
    ((-32768, 32767), (-32.768, 32.767))
    >>> sig.quantize([0.0012, 99.0]).tolist()
    [0.001, 32.767]
    """

    name: str
    start: int
    length: int
    signed: bool
    is_float: bool
    scale: float
    offset: float
    minimum: float | None
    maximum: float | None
    byte_order: str = "little_endian"
    is_multiplexer: bool = False
    multiplexer_signal: str | None = None
    multiplexer_ids: tuple[int, ...] | None = None

    @property
    def mask(self) -> int:
        """All ones over the signal's bits, ``(1 << length) - 1``."""
        return (1 << self.length) - 1

    @property
    def is_big_endian(self) -> bool:
        """Motorola byte order."""
        return self.byte_order == "big_endian"

    def raw_limits(self) -> tuple[int, int] | tuple[float, float]:
        """Representable raw range: integers, or the finite range of the float type."""
        if self.is_float:
            top = float(np.finfo(_float_dtype(self.length)).max)
            return -top, top
        if self.signed:
            return -(1 << (self.length - 1)), (1 << (self.length - 1)) - 1
        return 0, (1 << self.length) - 1

    def physical_limits(self) -> tuple[float, float]:
        """The range a value can take without clipping: the DBC's min/max within the raw range."""
        lo_raw, hi_raw = self.raw_limits()
        a, b = lo_raw * self.scale + self.offset, hi_raw * self.scale + self.offset
        lo, hi = min(a, b), max(a, b)
        if self.minimum is not None:
            lo = max(lo, self.minimum)
        if self.maximum is not None:
            hi = min(hi, self.maximum)
        return lo, hi

    def resolution_std(self, values: np.ndarray) -> float:
        """The standard deviation of the rounding error this signal's encoding adds to
        ``values`` (...): its step over sqrt(12) (uniform rounding); for a float signal the
        step is the float's spacing (one unit in the last place) at the largest values (the
        99.9th percentile of their magnitude): the rounding grows with the value, and a
        threshold set from a mean spacing would alarm wherever the values are large. A
        channel that carries no noise of its own (an echo of a setpoint, a quantised counter)
        has this much: the floor of any noise estimate.

        >>> SignalLayout("i_a", 32, 16, True, False, 0.001, 0.0, None, None).resolution_std(
        ...     [1.0, 2.0]) == 0.001 / 12**0.5
        True
        """
        v = np.asarray(values, dtype=float)
        v = v[np.isfinite(v)]
        if not self.is_float:
            return abs(self.scale) / math.sqrt(12.0)
        if v.size == 0:
            return 0.0
        top = np.percentile(np.abs((v - self.offset) / self.scale), 99.9)
        step = float(np.spacing(np.array(top).astype(_float_dtype(self.length)))) * abs(
            self.scale)
        return step / math.sqrt(12.0)

    def quantize(self, values: np.ndarray) -> np.ndarray:
        """Values as the receiver decodes them after a sender encodes them.

        The arithmetic of `MessageLayout.encode` then `MessageLayout.decode` without building
        payloads: clipped to the signal's range and rounded to its resolution (for a float
        signal, rounded to the float type; NaN and infinities pass).

        Parameters
        ----------
        values : (...) physical values.

        Returns
        -------
        (...) float64 quantized values.
        """
        v = np.asarray(values, dtype=float)
        lo, hi = self.physical_limits()
        if self.is_float:
            with np.errstate(over="ignore", invalid="ignore"):  # signalling NaNs pass
                v = np.where(np.isfinite(v), np.clip(v, lo, hi), v)
                raw = ((v - self.offset) / self.scale).astype(_float_dtype(self.length))
                return raw.astype(np.float64) * self.scale + self.offset
        v = np.clip(np.nan_to_num(v, nan=0.0), lo, hi)
        return np.rint((v - self.offset) / self.scale) * self.scale + self.offset


# -- the compiled plan --------------------------------------------------------------------------

_VIEW, _WORD, _WIDE = 0, 1, 2
_IDENTITY, _INTEGER, _LINEAR = 0, 1, 2


class _Field:
    """How one signal is read, scaled, selected and written (internal to a MessageLayout)."""

    __slots__ = (
        "big",
        "clip_raw",
        "conv",
        "dtype",
        "extra_shift",
        "hi",
        "ids",
        "ioffset",
        "is_float",
        "iscale",
        "left",
        "lo",
        "n",
        "name",
        "never",
        "offset",
        "parent",
        "raw_hi",
        "raw_lo",
        "scale",
        "sig",
        "signed",
        "u64",
        "view_at",
        "way",
        "wide",
        "window",
    )

    def __init__(self, sig: SignalLayout, length_bytes: int, width: int, where: str) -> None:
        self.sig = sig
        self.name = sig.name
        n = self.n = sig.length
        self.is_float = sig.is_float
        self.signed = sig.signed and not sig.is_float
        self.big = sig.is_big_endian
        if sig.byte_order not in ("little_endian", "big_endian"):
            raise ValueError(f"{where}: unknown byte order {sig.byte_order!r}")
        if sig.is_float:
            if n not in _FLOAT_BITS:
                raise ValueError(f"{where}: a float signal of {n} bits cannot be represented "
                                 "(16, 32 or 64 bits)")
        elif not 1 <= n <= 64:
            raise ValueError(f"{where}: an integer signal of {n} bits cannot be represented "
                             "(1 to 64 bits)")
        self.u64 = not sig.is_float and not sig.signed and n == 64
        # Bits of the signal in "network" order for Motorola (bit 0 = MSB of byte 0), in
        # little-endian order for Intel: first and last byte it touches.
        if self.big:
            msb = 8 * (sig.start // 8) + 7 - sig.start % 8
            first, last = msb // 8, (msb + n - 1) // 8
            lead = msb % 8  # bits before the MSB in the first byte
        else:
            first, last = sig.start // 8, (sig.start + n - 1) // 8
            lead = sig.start % 8  # bits below the LSB in the first byte
        if sig.start < 0 or last >= length_bytes:
            raise ValueError(f"{where}: the signal (start bit {sig.start}, {n} bits, "
                             f"{sig.byte_order}) does not fit in the {length_bytes}-byte payload")
        self.window = self.left = self.extra_shift = self.view_at = 0
        self.dtype = None
        self.wide = last - first >= 8
        if not self.wide:
            # A word of 8 bytes holding the field: the aligned one if it does, else one starting
            # at the field (within the padded buffer).
            w = 8 * (first // 8) if first // 8 == last // 8 else min(first, width - 8)
            self.window = w
            bit = 8 * (first - w) + lead  # Motorola: MSB from the top; Intel: LSB from bottom
            self.left = bit if self.big else 64 - bit - n
        else:  # over 56 bits spread over 9 bytes: the word at `first`, then one byte
            self.window = first
            self.extra_shift = lead if not self.big else 72 - lead - n
        if lead == 0 and n in _VIEW_BITS:
            self.way = _VIEW  # decoded through a typed view of the bytes
            kind = "f" if sig.is_float else ("i" if self.signed else "u")
            order = "|" if n == 8 else (">" if self.big else "<")
            self.dtype = np.dtype(f"{order}{kind}{n // 8}")
            self.view_at = first
        else:
            self.way = _WIDE if self.wide else _WORD
        # Conversion, as cantools' conversion classes compute it.
        self.scale, self.offset = float(sig.scale), float(sig.offset)
        self.iscale = self.ioffset = None
        self.raw_lo, self.raw_hi = sig.raw_limits()
        if self.scale == 1.0 and self.offset == 0.0:
            self.conv = _IDENTITY
        elif (not sig.is_float and self.scale.is_integer() and self.scale != 0
              and _fits_int64(self.raw_lo, self.raw_hi, int(self.scale),
                              int(self.offset) if self.offset.is_integer() else 0)):
            self.conv = _INTEGER
            self.iscale = int(self.scale)
            self.ioffset = int(self.offset) if self.offset.is_integer() else None
        else:
            self.conv = _LINEAR
        self.lo, self.hi = sig.physical_limits()
        self.clip_raw = (not sig.is_float and n > 52)  # rounding can leave the raw range
        self.parent = -1  # index of the multiplexer field, -1 for an always-present signal
        self.ids: np.ndarray | None = None
        self.never = False  # multiplexed by something cantools never decodes it under

    # -- decode -------------------------------------------------------------------------------
    def bits(self, buf: np.ndarray, words: dict) -> np.ndarray:
        """The field as it sits in the payload: a typed view, or uint64 raw bits (low n)."""
        if self.way == _VIEW:
            a = self.view_at
            return buf[:, a:a + self.dtype.itemsize].view(self.dtype)[:, 0]
        n = self.n
        if self.way == _WORD:
            t = _word(buf, words, self.big, self.window)
            if self.left:
                t = t << _U64(self.left)
            if self.signed:
                t = t.view(np.int64)
            return t >> (64 - n) if n < 64 else t
        w = _word(buf, words, self.big, self.window)
        extra = buf[:, self.window + 8].astype(np.uint64)
        s = self.extra_shift
        if self.big:  # 72-bit big-endian number: word then byte, field ends s bits from the end
            t = (w << _U64(8 - s)) | (extra >> _U64(s))
        else:  # field starts s bits into the word, its top bits are in the extra byte
            t = (w >> _U64(s)) | (extra << _U64(64 - s))
        if n < 64:
            t = t << _U64(64 - n)
            return (t.view(np.int64) if self.signed else t) >> (64 - n)
        return t.view(np.int64) if self.signed else t

    def raw(self, bits: np.ndarray) -> np.ndarray:
        """The raw value from `bits`: int64, uint64 (unsigned 64-bit) or float64 (floats)."""
        if self.is_float:
            if self.way != _VIEW:
                bits = bits.astype(_UINT[self.n]).view(_float_dtype(self.n))
            with np.errstate(invalid="ignore"):  # signalling NaNs come out quiet
                return bits.astype(np.float64)
        if self.way == _VIEW:  # a view of the payloads: always a copy
            return bits.astype(np.uint64 if self.u64 else np.int64)
        return bits if self.u64 or bits.dtype == np.int64 else bits.view(np.int64)

    def physical(self, bits: np.ndarray) -> np.ndarray:
        """Float64 physical values from `bits` (a fresh array)."""
        if self.is_float:
            x = self.raw(bits)
        elif self.conv == _INTEGER:
            r = self.raw(bits)
            r = r * self.iscale
            if self.ioffset is not None:
                if self.ioffset:
                    r += self.ioffset
                return r.astype(np.float64)
            x = r.astype(np.float64)
            x += self.offset
            return x
        elif bits.dtype == np.uint64 and not self.u64:
            x = bits.view(np.int64).astype(np.float64)  # under 64 bits: int64 converts faster
        else:
            x = bits.astype(np.float64)
        if self.conv == _LINEAR:
            # Signalling NaNs of float64 fields; a float64 times a large scale is inf, as
            # cantools decodes it.
            with np.errstate(invalid="ignore", over="ignore"):
                x *= self.scale
                if self.offset:
                    x += self.offset
        return x

    @property
    def number_dtype(self) -> np.dtype:
        """The dtype of `number`: exact integers where the physical value is one."""
        if self.is_float or self.conv == _LINEAR or (
                self.conv == _INTEGER and self.ioffset is None):
            return np.dtype(np.float64)
        return np.dtype(np.uint64 if self.u64 and self.conv == _IDENTITY else np.int64)

    def number(self, raw: np.ndarray) -> np.ndarray:
        """The multiplexer value cantools selects by, int(physical), from the raw value."""
        kind = self.number_dtype
        if kind.kind != "f":
            if self.conv == _IDENTITY:
                return raw
            return raw.astype(np.int64) * self.iscale + self.ioffset
        with np.errstate(invalid="ignore"):
            return np.trunc(raw.astype(np.float64) * self.scale + self.offset)


_C_CONV = {_IDENTITY: "identity", _LINEAR: "linear"}


class FieldPlan(NamedTuple):
    """One compiled signal as `MessageLayout.plan` gives it.

    signal : its layout. conv : "identity", "integer" (raw * iscale + ioffset, exact),
    "integer_float" (raw * iscale exact, then + offset) or "linear" (raw * scale + offset).
    parent : the plan's row of the multiplexer that selects it, -1 none. ids : the multiplexer
    values that select it, as its multiplexer's number kind ("int", "uint" or "real") holds
    them. never : nothing ever selects it.

    Examples
    --------
    >>> m = SignalLayout("Mux", 0, 8, False, False, 1.0, 0.0, None, None, is_multiplexer=True)
    >>> v = SignalLayout("V", 8, 16, True, False, 0.5, 0.0, None, None,
    ...                  multiplexer_signal="Mux", multiplexer_ids=(2,))
    >>> mux, volts = MessageLayout("M", 0x10, 8, (m, v), ()).plan()
    >>> mux.conv, mux.number, volts.conv, volts.parent, volts.ids
    ('identity', 'int', 'linear', 0, (2,))
    """

    signal: SignalLayout
    conv: str
    iscale: int
    ioffset: int
    parent: int
    ids: tuple
    number: str
    never: bool


def _fits_int64(lo: int, hi: int, scale: int, offset: int) -> bool:
    ends = (lo * scale + offset, hi * scale + offset, lo * scale, hi * scale)
    return all(-(1 << 63) <= e < (1 << 63) for e in ends)


def _word(buf: np.ndarray, words: dict, big: bool, window: int) -> np.ndarray:
    """(N,) uint64: payload bytes window..window+7 as a little-endian number (Intel) or a
    big-endian one (Motorola), computed once per decode and kept in ``words``."""
    key = (big, window)
    got = words.get(key)
    if got is None:
        src = buf[:, window:window + 8]
        if window % 8:
            src = np.ascontiguousarray(src)
        got = src.view(">u8" if big else "<u8")[:, 0].astype(np.uint64, copy=False)
        words[key] = got
    return got


def _select(number: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """(N,) bool: number is one of ids."""
    if ids.size <= 1:
        return number == ids[0] if ids.size else np.zeros(number.shape, dtype=bool)
    if ids.size <= 8:
        out = number == ids[0]
        for i in ids[1:]:
            out |= number == i
        return out
    return np.isin(number, ids)


def _ids_for(number_dtype: np.dtype, ids: tuple[int, ...]) -> np.ndarray:
    if number_dtype == np.uint64:
        return np.array([i for i in ids if 0 <= i < 1 << 64], dtype=np.uint64)
    if number_dtype.kind == "f":
        return np.array(ids, dtype=np.float64)
    return np.array([i for i in ids if -(1 << 63) <= i < 1 << 63], dtype=np.int64)


# -- the message ----------------------------------------------------------------------------------

@dataclass(frozen=True)
class MessageLayout:
    """A compiled message: ID, length and its signals, with block encode and decode.

    Attributes
    ----------
    name, frame_id : the DBC message name and ID (without the extended-frame flag bit).
    dlc : the payload length in bytes (up to 64 for CAN FD).
    signals : the compiled signals, in the message's order.
    senders : the DBC senders.
    is_extended : 29-bit ID.
    is_fd : a CAN FD frame.

    Examples
    --------
    >>> import cantools
    >>> from cantools.database.conversion import BaseConversion
    >>> sig = cantools.database.can.Signal("Speed", start=7, length=12, byte_order="big_endian",
    ...                                    conversion=BaseConversion.factory(scale=0.5))
    >>> msg = cantools.database.can.Message(frame_id=0x18FEF100, name="CCVS", length=8,
    ...                                     signals=[sig], is_extended_frame=True)
    >>> layout = compile_layout(msg)
    >>> payloads, clipped = layout.encode({"Speed": np.array([1.5, 100.0])}, 2)
    >>> payloads[:, :2].tolist(), clipped
    ([[0, 48], [12, 128]], {})
    >>> layout.decode(payloads)["Speed"].tolist(), layout.is_extended
    ([1.5, 100.0], True)
    """

    name: str
    frame_id: int
    dlc: int
    signals: tuple[SignalLayout, ...]
    senders: tuple[str, ...]
    is_extended: bool = False
    is_fd: bool = False
    _fields: tuple[_Field, ...] = field(init=False, repr=False, compare=False)
    _width: int = field(init=False, repr=False, compare=False)
    _reach: int = field(init=False, repr=False, compare=False)
    _views_only: bool = field(init=False, repr=False, compare=False)
    _order: dict = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        width = max(8, -(-self.dlc // 8) * 8)
        fields = [_Field(sig, self.dlc, width, f"{self.name}.{sig.name}") for sig in self.signals]
        by_name = {f.name: i for i, f in enumerate(fields)}
        for f in fields:
            parent = f.sig.multiplexer_signal
            if parent is None:
                continue
            p = by_name.get(parent)
            if p is None or not fields[p].sig.is_multiplexer or f.sig.multiplexer_ids is None:
                f.never = True  # cantools never reaches it
                continue
            f.parent = p
        # Depth-first: a multiplexer before what it selects; cycles are never reached.
        depth: dict[int, int] = {}

        def depth_of(i: int, seen: tuple[int, ...] = ()) -> int:
            if i in depth:
                return depth[i]
            f = fields[i]
            if f.parent < 0:
                d = 0
            elif f.parent in seen:
                f.never, d = True, 0
            else:
                d = depth_of(f.parent, (*seen, i)) + 1
                if fields[f.parent].never:
                    f.never = True
            depth[i] = d
            return d

        for i in range(len(fields)):
            depth_of(i)
        order = sorted(range(len(fields)), key=lambda i: depth[i])
        position = {i: k for k, i in enumerate(order)}
        ordered = [fields[i] for i in order]
        for f in ordered:
            if f.parent >= 0:
                f.parent = position[f.parent]
        for f in ordered:
            if f.parent >= 0 and not f.never:
                f.ids = _ids_for(ordered[f.parent].number_dtype, f.sig.multiplexer_ids or ())
        object.__setattr__(self, "_fields", tuple(ordered))
        object.__setattr__(self, "_width", width)
        # Bytes the decode reads: a typed view reads its own; a word 8 from its window.
        reach = [f.view_at + f.dtype.itemsize if f.way == _VIEW else
                 f.window + (9 if f.way == _WIDE else 8) for f in ordered]
        object.__setattr__(self, "_reach", max(reach, default=0))
        object.__setattr__(self, "_views_only", all(f.way == _VIEW for f in ordered))
        object.__setattr__(self, "_order", dict.fromkeys(sig.name for sig in self.signals))

    @property
    def length(self) -> int:
        """The payload length in bytes (same as ``dlc``)."""
        return self.dlc

    @property
    def is_multiplexed(self) -> bool:
        """Some signal is selected by a multiplexer."""
        return any(s.multiplexer_signal is not None for s in self.signals)

    def plan(self) -> tuple[FieldPlan, ...]:
        """How each compiled signal is read, as the C core's tables take it
        (canfdi.bus.ctables): multiplexers before what they select."""
        out = []
        for f in self._fields:
            conv = (_C_CONV[f.conv] if f.conv != _INTEGER else
                    "integer" if f.ioffset is not None else "integer_float")
            kind = f.number_dtype
            out.append(FieldPlan(
                f.sig, conv, f.iscale or 0, f.ioffset or 0, f.parent,
                () if f.ids is None else tuple(f.ids.tolist()),
                "real" if kind.kind == "f" else "uint" if kind == np.uint64 else "int",
                f.never))
        return tuple(out)

    def signal(self, name: str) -> SignalLayout:
        """The compiled signal called ``name`` (KeyError naming the message if none)."""
        for sig in self.signals:
            if sig.name == name:
                return sig
        raise KeyError(f"{self.name} has no signal {name!r}")

    # -- decode -------------------------------------------------------------------------------
    def _buffer(self, payloads: np.ndarray) -> np.ndarray:
        """(N, >= reach) uint8 with contiguous rows: the payloads themselves when every read
        can be a view of them, else a copy cut or zero-padded to the bytes the reads touch."""
        p = check_shape("payloads", payloads, ("N", "L"))
        if p.dtype != np.uint8:
            p = p.astype(np.uint8)
        n, have = p.shape
        reach = self._reach
        if have >= reach and p.strides[1] == 1 and (
                self._views_only or (p.strides[0] % 8 == 0 and p.ctypes.data % 8 == 0)):
            return p
        if have >= reach:
            return np.ascontiguousarray(p[:, :reach])
        buf = np.zeros((n, reach), dtype=np.uint8)
        buf[:, :have] = p
        return buf

    def _read(self, payloads: np.ndarray, physical: bool
              ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
        """Values (physical or raw) of every signal, and the selection of multiplexed ones."""
        buf = self._buffer(payloads)
        words: dict = {}
        fields = self._fields
        values: dict[str, np.ndarray] = {}
        selected: dict[str, np.ndarray] = {}
        numbers: list[np.ndarray | None] = [None] * len(fields)
        selection: list[np.ndarray | None] = [None] * len(fields)
        cache: dict = {}
        n = buf.shape[0]
        values.update(self._order)  # the message's order, whatever the order of the reads
        for k, f in enumerate(fields):
            bits = f.bits(buf, words)
            if f.sig.is_multiplexer or not physical:
                raw = f.raw(bits)
                if f.sig.is_multiplexer:
                    numbers[k] = f.number(raw)
                value = f.physical(bits) if physical else raw
            else:
                value = f.physical(bits)
            if f.never:
                sel = np.zeros(n, dtype=bool)
            elif f.parent >= 0:
                key = (f.parent, f.ids.tobytes())
                sel = cache.get(key)
                if sel is None:
                    sel = _select(numbers[f.parent], f.ids)
                    up = selection[f.parent]
                    if up is not None:
                        sel &= up
                    cache[key] = sel
            else:
                sel = None
            if sel is not None:
                selection[k] = sel
                selected[f.name] = sel
                if physical:
                    value[~sel] = np.nan
            values[f.name] = value
        return values, selected

    def decode(self, payloads: np.ndarray) -> dict[str, np.ndarray]:
        """Physical values of every signal.

        Parameters
        ----------
        payloads : (N, L) uint8, L >= ``dlc`` (bytes beyond are ignored; a shorter payload is
            read as if zero-padded).

        Returns
        -------
        signal name -> (N,) float64 physical values, as cantools'
        ``decode(data, decode_choices=False, scaling=True)``; NaN where a multiplexed signal is
        not selected by its multiplexer.
        """
        return self._read(payloads, physical=True)[0]

    def decode_raw(self, payloads: np.ndarray) -> dict[str, np.ndarray]:
        """Raw values before scaling, exact.

        Parameters
        ----------
        payloads : (N, L) uint8, as for `decode`.

        Returns
        -------
        signal name -> (N,) raw values: int64 for integer signals, uint64 for unsigned 64-bit
        ones, float64 for float signals; as cantools' ``decode(data, decode_choices=False,
        scaling=False)``. Multiplexed signals hold the payload's bits in every row: see
        `selected` for where they are present.
        """
        return self._read(payloads, physical=False)[0]

    def selected(self, payloads: np.ndarray) -> dict[str, np.ndarray]:
        """Where each multiplexed signal is present.

        Parameters
        ----------
        payloads : (N, L) uint8, as for `decode`.

        Returns
        -------
        multiplexed signal name -> (N,) bool, True where its multiplexers select it (where
        cantools' decode has it in its dict). Signals that are always present are left out.
        """
        return self._read(payloads, physical=False)[1]

    # -- encode -------------------------------------------------------------------------------
    def encode(self, values: dict[str, np.ndarray], count: int
               ) -> tuple[np.ndarray, dict[str, int]]:
        """Encode ``count`` frames from physical values.

        Parameters
        ----------
        values : signal name -> (count,) physical values; missing signals are encoded as raw 0.
            A multiplexer's value (as quantized) selects which multiplexed signals are written
            in each row; the others' values are ignored there (NaN is fine).
        count : number of frames.

        Returns
        -------
        payloads : (count, dlc) uint8.
        clipped : signal name -> number of values clipped to the signal's physical range
            (integers: NaN and infinities too; floats: finite values only), counted in the rows
            where the signal is written.
        """
        return self._write(values, count, scaled=True)

    def encode_raw(self, values: dict[str, np.ndarray], count: int
                   ) -> tuple[np.ndarray, dict[str, int]]:
        """Encode ``count`` frames from raw values (exact up to 64 bits), like
        cantools' ``encode(data, scaling=False)``.

        Parameters
        ----------
        values : signal name -> (count,) raw values (integers of any numpy integer dtype, or
            floats, rounded; float signals take floats); missing signals are encoded as 0.
        count : number of frames.

        Returns
        -------
        payloads : (count, dlc) uint8.
        clipped : signal name -> number of values clipped to the raw range.
        """
        return self._write(values, count, scaled=False)

    def _write(self, values: dict[str, np.ndarray], count: int, scaled: bool
               ) -> tuple[np.ndarray, dict[str, int]]:
        fields = self._fields
        width = self._width
        acc: dict[tuple[bool, int], np.ndarray] = {}
        extra: dict[int, np.ndarray] = {}
        clipped: dict[str, int] = {}
        numbers: list[np.ndarray | None] = [None] * len(fields)
        selection: list[np.ndarray | None] = [None] * len(fields)
        for k, f in enumerate(fields):
            if f.never:
                continue
            sel = None
            if f.parent >= 0:
                sel = _select(numbers[f.parent], f.ids)
                up = selection[f.parent]
                if up is not None:
                    sel &= up
                selection[k] = sel
            given = values.get(f.name)
            if given is None or (sel is not None and not sel.any()):
                if f.sig.is_multiplexer:  # raw 0
                    numbers[k] = f.number(np.zeros(count, dtype=np.uint64 if f.u64 else
                                                   np.float64 if f.is_float else np.int64))
                continue
            v = check_shape(f"values[{f.name!r}]", given, (count,))
            raw, bad = _to_raw(f, v, scaled)
            if bad is not None:
                if sel is not None:
                    bad &= sel
                hits = int(np.count_nonzero(bad))
                if hits:
                    clipped[f.name] = hits
            if f.sig.is_multiplexer:
                numbers[k] = f.number(raw)
            _place(f, raw, sel, acc, extra)
        if len(acc) == 1 and width == 8:  # one word is the whole payload: no copy
            ((big, _), word), = acc.items()
            buf = word.astype(">u8" if big else "<u8", copy=False).view(np.uint8)
            buf = buf.reshape(count, 8)
        else:
            buf = np.zeros((count, width), dtype=np.uint8)
            for (big, w), a in acc.items():
                a = a.astype(">u8" if big else "<u8", copy=False)
                buf[:, w:w + 8] |= a.view(np.uint8).reshape(count, 8)
            for at, e in extra.items():
                buf[:, at] |= e.astype(np.uint8)
        return np.ascontiguousarray(buf[:, :self.dlc]), clipped


def _to_raw(f: _Field, v: np.ndarray, scaled: bool
            ) -> tuple[np.ndarray, np.ndarray | None]:
    """Raw values of field f from given values: (raw int64/uint64/float, clipped-mask or None)."""
    if f.is_float:
        v = np.asarray(v, dtype=np.float64)
        lo, hi = (f.lo, f.hi) if scaled else (f.raw_lo, f.raw_hi)
        with np.errstate(over="ignore", invalid="ignore"):  # signalling NaNs pass
            bad = np.isfinite(v) & ((v < lo) | (v > hi))
            if bad.any():
                v = np.where(bad, np.clip(v, lo, hi), v)
            else:
                bad = None
            if scaled and f.conv != _IDENTITY:
                v = (v - f.offset) / f.scale
            return v.astype(_float_dtype(f.n)).astype(np.float64), bad
    target = np.uint64 if f.u64 else np.int64
    if not scaled and v.dtype.kind in "iub":
        # Exact integers: compare as Python-sized values through a common dtype.
        if v.dtype == np.uint64:
            bad = v > np.uint64(f.raw_hi)
            if bad.any():
                v = np.minimum(v, np.uint64(f.raw_hi))
            else:
                bad = None
            return v.astype(target), bad
        v = v.astype(np.int64)
        lo = max(f.raw_lo, -(1 << 63))
        hi = min(f.raw_hi, (1 << 63) - 1)
        bad = (v < lo) | (v > hi)
        if bad.any():
            v = np.clip(v, lo, hi)
        else:
            bad = None
        return v.astype(target), bad
    v = np.asarray(v, dtype=np.float64)
    if scaled:
        lo, hi = f.lo, f.hi
    else:
        lo, hi = float(f.raw_lo), float(f.raw_hi)
    bad = ~((v >= lo) & (v <= hi))
    if bad.any():
        v = np.clip(np.nan_to_num(v, nan=0.0), lo, hi)
    else:
        bad = None
    if scaled and f.conv != _IDENTITY:
        v = (v - f.offset) / f.scale
    r = np.rint(v)
    if f.clip_raw:
        r = np.clip(r, _float_at_least(f.raw_lo), _float_at_most(f.raw_hi))
    return r.astype(target), bad


def _place(f: _Field, raw: np.ndarray, sel: np.ndarray | None, acc: dict, extra: dict) -> None:
    """OR the raw values of field f into the words (and ninth bytes) of the payload."""
    if f.is_float:
        with np.errstate(over="ignore"):
            b = raw.astype(_float_dtype(f.n)).view(_UINT[f.n]).astype(np.uint64)
    else:
        b = raw.view(np.uint64)
        if f.n < 64:
            b = b & _U64((1 << f.n) - 1)
    if sel is not None:
        b = np.where(sel, b, _U64(0))
    key = (f.big, f.window)
    if not f.wide:
        shift = 64 - f.left - f.n
        part = b << _U64(shift) if shift else b
        acc[key] = part if key not in acc else acc[key] | part
        return
    s = f.extra_shift
    if f.big:
        word, tail = b >> _U64(8 - s), (b << _U64(s)) & _U64(0xFF)
    else:
        word, tail = b << _U64(s), b >> _U64(64 - s)
    at = f.window + 8
    acc[key] = word if key not in acc else acc[key] | word
    extra[at] = tail if at not in extra else extra[at] | tail


def compile_layout(message, signals=None) -> MessageLayout:
    """Compile a cantools Message.

    Parameters
    ----------
    message : cantools ``Message`` (not a container).
    signals : names of the signals to compile (the multiplexers they need are added), or None
        for all.

    Returns
    -------
    MessageLayout

    Raises
    ------
    ValueError
        Naming the message and signal, for a signal that cannot be represented (a float of a
        width other than 16/32/64 bits, an integer over 64 bits, bits outside the payload), a
        name the message does not have, or a container message.
    """
    if getattr(message, "is_container", False):
        raise ValueError(f"{message.name}: container messages are not supported")
    by_name = {sig.name: sig for sig in message.signals}
    if signals is None:
        wanted = set(by_name)
    else:
        wanted = set()
        for name in signals:
            if name not in by_name:
                raise ValueError(f"{message.name}.{name}: no such signal in the message")
            while name is not None and name in by_name and name not in wanted:
                wanted.add(name)
                name = by_name[name].multiplexer_signal
    compiled = []
    for sig in message.signals:
        if sig.name not in wanted:
            continue
        ids = sig.multiplexer_ids
        compiled.append(SignalLayout(
            name=sig.name, start=sig.start, length=sig.length, signed=bool(sig.is_signed),
            is_float=bool(sig.is_float), scale=float(sig.scale), offset=float(sig.offset),
            minimum=None if sig.minimum is None else float(sig.minimum),
            maximum=None if sig.maximum is None else float(sig.maximum),
            byte_order=sig.byte_order, is_multiplexer=bool(sig.is_multiplexer),
            multiplexer_signal=sig.multiplexer_signal,
            multiplexer_ids=None if ids is None else tuple(int(i) for i in ids),
        ))
    return MessageLayout(name=message.name, frame_id=message.frame_id, dlc=message.length,
                         signals=tuple(compiled), senders=tuple(message.senders or ()),
                         is_extended=bool(message.is_extended_frame),
                         is_fd=bool(message.is_fd))
