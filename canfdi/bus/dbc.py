"""The DBC side of the bus: where one drive's model signals are, compiled once.

`BusMap.from_config` reads the drive's DBC as its vendor publishes it and the config's bus
section (docs/bus.md): each model input and output is mapped to a (message, signal) of the DBC
(`bus.map`, or the same-named signal in the one message that carries it), the messages' IDs
follow the node-id template for the drive (canfdi.bus.nodeid), each mapped message gets its
end-to-end profile (canfdi.bus.e2e) and only its used signals are compiled (canfdi.bus.codec).
The used messages are the drive's *slots*; a trigger clock's message is a slot too, with no
signal of its own. Every other message of the DBC (and the other drives') is known and
"unused"; the monitor's own frames are "monitor".

`BusMap.decode_frame` checks and decodes one frame; `BusMap.decode_frames` a whole `FrameBlock`
with numpy. Statuses are canfdi.bus.frames' ``STATUS_NAMES``: ``error_frame``, ``remote`` (a
request for an ID no message has; one for a known message, as a master polling it, is
``unused``), ``unknown_id`` (11-bit) / ``extended`` (29-bit) for an ID no message has, ``fd``
for a frame whose FD flag is not its message's, ``dlc``, ``crc`` (the E2E check failed),
``monitor``, ``unused``, ``ok``; ``implausible`` for a mapped value outside its range and
``saturated`` for one at a limit of what its signal can carry (`_clip_limits`).
"""

from __future__ import annotations

import logging
import math
import struct
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from canfdi.bus.codec import MessageLayout, SignalLayout, compile_layout
from canfdi.bus.ctables import BusTables, EntrySpec, SlotSpec, build_tables
from canfdi.bus.e2e import E2EProfile, make_profile
from canfdi.bus.frames import (
    FLAG_ERROR,
    FLAG_EXTENDED,
    FLAG_FD,
    FLAG_REMOTE,
    MAX_DATA,
    STATUS_CODES,
    FrameBlock,
)
from canfdi.bus.nodeid import MAX_STANDARD_ID, frame_id
from canfdi.core.settings import (
    BusConfig,
    ConfigError,
    DriveConfig,
    MonitorConfig,
    SignalRef,
    brief,
    nearest,
)

if TYPE_CHECKING:
    from cantools.database.can import Database, Message

__all__ = ["BusMap", "Known", "MessageKey", "find_message", "keys_of", "load_dbc", "message_key"]

_IMPLAUSIBLE = STATUS_CODES["implausible"]
_SATURATED = STATUS_CODES["saturated"]
(_OK, _MONITOR, _UNUSED, _UNKNOWN_ID, _EXTENDED, _REMOTE, _ERROR, _FD, _DLC, _CRC) = (
    STATUS_CODES[name] for name in ("ok", "monitor", "unused", "unknown_id", "extended",
                                    "remote", "error_frame", "fd", "dlc", "crc"))
_F32 = struct.Struct("<f")

MessageKey = tuple[int, bool]
"""A frame's identity on the bus: (arbitration ID, extended)."""


def message_key(frame_id: int, extended: bool) -> MessageKey:
    return int(frame_id), bool(extended)


def load_dbc(value: str, config_path: Path | None, field: str = "bus.dbc"
             ) -> tuple[Database, str]:
    """The database named (a DBC shipped in canfdi.dbc) or pointed to (a file, relative to the
    config's directory) by ``value``, and a label for messages; ConfigError(field) if not."""
    import cantools

    from canfdi import dbc as dbc_files

    if Path(value).name == value and value.removesuffix(".dbc") in dbc_files.available():
        return dbc_files.load(value), value.removesuffix(".dbc")
    candidate = Path(value).expanduser()
    if not candidate.is_absolute() and config_path is not None:
        candidate = Path(config_path).parent / candidate
    if not candidate.is_file():
        shipped = ", ".join(dbc_files.available()) or "none"
        raise ConfigError(field, f"no DBC file {candidate} and no shipped DBC named "
                                 f"{brief(value)} (shipped: {shipped})")
    # cantools warns of a message overwritten by another of the same ID; check_unique_ids
    # makes that the config error, said once.
    quiet = logging.getLogger("cantools.database")
    level = quiet.level
    quiet.setLevel(logging.ERROR)
    try:
        database = cantools.database.load_file(candidate, database_format="dbc", strict=False)
    except (OSError, ValueError, cantools.database.Error) as exc:
        raise ConfigError(field, f"cannot load {candidate}: {exc}") from None
    finally:
        quiet.setLevel(level)
    check_unique_ids(database, field, str(candidate))
    return database, str(candidate)  # type: ignore[return-value]


def check_unique_ids(database: Database, field: str, label: str) -> None:
    """ConfigError(field) naming two messages of one ID (which one would a frame be?)."""
    seen: dict[MessageKey, str] = {}
    for message in database.messages:
        key = message_key(message.frame_id, message.is_extended_frame)
        if key in seen:
            raise ConfigError(field, f"{label}: messages {seen[key]} and {message.name} have the "
                                     f"same ID 0x{message.frame_id:X}")
        seen[key] = message.name


def signal_bits(signal) -> frozenset[int]:
    """The payload bits a DBC signal occupies, numbered 8 * byte + bit (bit 0 the LSB):
    Intel signals run up from their start bit, Motorola ones down from their MSB, on to the
    next byte's bit 7.

    >>> import cantools
    >>> sorted(signal_bits(cantools.database.can.Signal("s", start=7, length=10,
    ...                                                 byte_order="big_endian")))
    [0, 1, 2, 3, 4, 5, 6, 7, 14, 15]
    """
    if signal.byte_order == "little_endian":
        return frozenset(range(signal.start, signal.start + signal.length))
    bits, pos = set(), signal.start
    for _ in range(signal.length):
        bits.add(pos)
        pos = pos + 15 if pos % 8 == 0 else pos - 1
    return frozenset(bits)


def check_no_overlap(message: Message, names: list[str], field: str, label: str) -> None:
    """ConfigError(field) when a mapped signal shares payload bits with another signal of its
    message (multiplexed signals aside: they take turns)."""
    plain = [sig for sig in message.signals if not sig.multiplexer_ids]
    bits = {sig.name: signal_bits(sig) for sig in plain}
    for name in names:
        if name not in bits:
            continue
        for other in plain:
            if other.name != name and bits[name] & bits[other.name]:
                raise ConfigError(field, f"{label}: signals {name} and {other.name} of "
                                         f"{message.name} overlap (bits "
                                         f"{sorted(bits[name] & bits[other.name])[:4]}...)")


def find_message(database: Database, ref: str | int, field: str, label: str) -> Message:
    """The DBC message of that name or (DBC) ID; ConfigError(field) naming the nearest."""
    if isinstance(ref, int):
        for message in database.messages:
            if message.frame_id == ref:
                return message
        ids = ", ".join(f"0x{m.frame_id:X}" for m in database.messages)
        raise ConfigError(field, f"no message with ID 0x{ref:X} in {label} (IDs: {ids})")
    for message in database.messages:
        if message.name == ref:
            return message
    names = [m.name for m in database.messages]
    close = nearest(ref, names)
    hint = f"did you mean {' or '.join(close)}? " if close else ""
    raise ConfigError(field, f"no message {brief(ref)} in {label} ({hint}messages: "
                             f"{', '.join(names)})")


def _carriers(database: Database, signal: str) -> list[Message]:
    return [m for m in database.messages if any(s.name == signal for s in m.signals)]


def _resolve(database: Database, name: str, ref: SignalRef | None, label: str
             ) -> tuple[Message, str]:
    """The (message, signal) that carries model signal ``name``."""
    field = f"bus.map.{name}"
    if ref is None:
        found = _carriers(database, name)
        if len(found) == 1:
            return found[0], name
        if len(found) > 1:
            where = ", ".join(m.name for m in found)
            raise ConfigError(field, f"signal {brief(name)} is in {len(found)} messages of {label} "
                                     f"({where}): map it to one of them")
        every = sorted({s.name for m in database.messages for s in m.signals})
        close = nearest(name, every)
        hint = f"; nearest signals: {', '.join(close)}" if close else ""
        raise ConfigError(field, f"no signal {brief(name)} in {label}: map the model signal to the "
                                 f"DBC signal that carries it (bus.map.{name}: MESSAGE.SIGNAL)"
                                 f"{hint}")
    message = find_message(database, ref.message, f"{field}.message", label)
    if any(s.name == ref.signal for s in message.signals):
        return message, ref.signal
    close = nearest(ref.signal, [s.name for s in message.signals])
    hint = f"did you mean {' or '.join(close)}? " if close else ""
    elsewhere = [m.name for m in _carriers(database, ref.signal)]
    carriers = (f"; {ref.signal!r} is in {', '.join(elsewhere)}" if elsewhere else "")
    raise ConfigError(f"{field}.signal", f"no signal {brief(ref.signal)} in {message.name} ({hint}"
                                         f"signals: {', '.join(s.name for s in message.signals)})"
                                         f"{carriers}")


def _plausible(message: Message, signal: str, ref: SignalRef | None) -> tuple[float, float]:
    """The range a mapped signal's values must fall in: the config's ``range``, else the
    DBC's [minimum|maximum] when it states one ([0|0] states none), widened by half a step of
    the signal's resolution (a value at the limit, rounded); (-inf, inf) otherwise."""
    sig = message.get_signal_by_name(signal)
    if ref is not None and ref.range is not None:
        low, high = ref.range
    elif (sig.minimum is not None and sig.maximum is not None
          and (sig.minimum, sig.maximum) != (0, 0) and sig.minimum < sig.maximum):
        low, high = float(sig.minimum), float(sig.maximum)
    else:
        return -math.inf, math.inf
    slack = abs(float(sig.scale or 0.0)) / 2.0 if not sig.is_float else 0.0
    return low - slack, high + slack


def _clip_limits(sig: SignalLayout) -> tuple[float, float]:
    """(low, high): a mapped value at or beyond either is *saturated*: the sender clipped it to
    what the signal can carry (`SignalLayout.physical_limits`: the DBC's [minimum|maximum]
    within the raw range), so it says only that the quantity is at or beyond the limit. Each
    limit is the value a clipped one decodes to (the limit encoded: a DBC's limit need not lie
    on the signal's steps, as opendbc's Tesla DI_vehicleSpeed, 0.08 kph steps up to 285, whose
    top is 284.96) moved in by half a step, so that another rounding of it still counts and
    the next step in does not. A limit at 0 is none: zero is where a quantity rests (a motor
    at standstill, no current), and a signal that can go below it has a signed range. A float
    signal has none: its range is where its type ends, which no drive's value reaches.

    >>> _clip_limits(SignalLayout("v", 0, 16, True, False, 0.002, 0.0, -65.536, 65.534))
    (-65.535, 65.533)
    >>> _clip_limits(SignalLayout("n", 0, 16, False, False, 1.0, 0.0, 0.0, 100.0))
    (-inf, 99.5)
    """
    if sig.is_float:
        return -math.inf, math.inf
    lo, hi = (float(v) for v in sig.quantize(np.array(sig.physical_limits())))
    half = abs(sig.scale) / 2.0
    return (-math.inf if abs(lo) < half else lo + half,
            math.inf if abs(hi) < half else hi - half)


def _profile(e2e: Any, message: Message, key: MessageKey, explicit_only: bool) -> E2EProfile:
    """The E2E profile of a message on this bus. A slot takes its configured profile (the
    default when not listed); a message that is no slot only a profile configured for it by
    name or ID, or canfdi's when that is the default and the message has canfdi's header:
    other messages of a vendor's DBC are not checked."""
    spec, where = _profile_spec(e2e, message)
    places = _signal_places(message)
    if explicit_only and where == "bus.e2e.default":
        name = spec if isinstance(spec, str) else spec.get("profile")
        if name != "canfdi" or not _has_canfdi_header(places):
            spec = "none"
    if (spec == "canfdi" or (isinstance(spec, dict) and spec.get("profile") == "canfdi")) \
            and not _has_canfdi_header(places):
        raise ConfigError(where, f"{message.name} has no canfdi E2E header (CRC at bits 0|8, "
                                 "Counter at 8|8): give it its own profile (bus.e2e.messages."
                                 f"{message.name}: none, counter, ...)")
    return make_profile(spec, key[0], key[1], message.length, places, where)


def _has_canfdi_header(places: dict[str, tuple[int, int, str]]) -> bool:
    return (places.get("CRC", (None, None))[:2] == (0, 8)
            and places.get("Counter", (None, None))[:2] == (8, 8))


def _profile_spec(e2e: Any, message: Message) -> tuple[Any, str]:
    """The E2E spec of a message (by name, else by DBC ID, else the default) and its field."""
    for key in (message.name, message.frame_id):
        if key in e2e.messages:
            return e2e.messages[key], f"bus.e2e.messages.{key}"
    return e2e.default, "bus.e2e.default"


def _signal_places(message: Message) -> dict[str, tuple[int, int, str]]:
    return {s.name: (s.start, s.length, s.byte_order) for s in message.signals}


@dataclass(frozen=True)
class _Slot:
    """A used message of the drive: its compiled layout (only the used signals), its ID on
    this drive, its E2E profile, the model fields it carries (signal, "u"/"z", index) in the
    order values come out, and the positions of those values in the flat [u, z] buffer."""

    layout: MessageLayout
    key: MessageKey
    e2e: E2EProfile
    fields: tuple[tuple[str, str, int], ...]
    dests: tuple[int, ...]
    program: tuple | None  # the scalar fast path (Intel, <= 8 bytes), or None
    low: tuple[float, ...] = ()  # per field, the plausible range (-inf, inf: none)
    high: tuple[float, ...] = ()
    checked: bool = False  # whether any field has a range
    clip_low: tuple[float, ...] = ()  # per field, where the sender clips (`_clip_limits`)
    clip_high: tuple[float, ...] = ()

    def saturated(self, values: np.ndarray) -> np.ndarray:
        """(...) whether a row of decoded field values (..., fields) has one at a limit of
        what its signal can carry; NaN never is."""
        v = np.asarray(values, dtype=float)
        return ((v <= np.array(self.clip_low)) | (v >= np.array(self.clip_high))).any(axis=-1)


@dataclass(frozen=True)
class Known:
    """A known message that is no slot: "monitor" (the monitor's own) or "unused" (the DBC's
    other messages, the other drives'), checked for its length, FD flag and E2E profile.

    Examples
    --------
    >>> from canfdi.bus.e2e import make_profile
    >>> known = Known("unused", 4, False, make_profile("none", 0x2A0, False, 4, {}, "bus.e2e"))
    >>> known.kind, known.length, known.e2e.check(bytes(4))
    ('unused', 4, True)
    """

    kind: str
    length: int
    fd: bool
    e2e: E2EProfile


def _program(layout: MessageLayout, fields: Sequence[tuple[str, str, int]]) -> tuple | None:
    """(start, mask, sign, scale, offset, is_float) per field for the scalar decode (integer
    shifts, no numpy) when it reads every field as the codec does: Intel integers and unscaled
    float32 within 8 bytes, none multiplexed; None otherwise (decode through the layout)."""
    if layout.dlc > MAX_DATA:
        return None
    out = []
    for name, _, _ in fields:
        sig = layout.signal(name)
        if (sig.is_big_endian or sig.multiplexer_signal is not None
                or sig.start + sig.length > 64
                or (sig.is_float and (sig.length != 32 or sig.scale != 1 or sig.offset != 0))):
            return None
        sign = 1 << (sig.length - 1) if sig.signed and not sig.is_float else 0
        out.append((sig.start, sig.mask, sign, sig.scale, sig.offset, sig.is_float))
    return tuple(out)


class BusMap:
    """One drive's model signals on the bus (build it with `from_config`).

    Attributes (read-only by convention)
    ----------
    dbc_label : the DBC's name or path, for messages. drive : the drive's name.
    input_names, output_names : (p,), (q,) the model's signal names.
    layouts : (M,) compiled layouts of the slots (used messages, ascending ID).
    fields : (M,) per slot, its (signal, "u"/"z", index) triples in decode order.
    keys : (M,) per slot, its (ID on this drive, extended).
    e2e : (M,) per slot, its E2E profile.
    slot_of : (ID, extended) -> slot.
    trigger_slot : the slot of a trigger clock's message, or None.
    counter_modulus : the alive counter modulus every slot shares, or None when one has none
        (the counter clock needs it).
    n_signals_max : width of the values of `decode_frames` (most fields in one slot).

    Examples
    --------
    The shipped dc_motor config's drive; a frame decodes to (status, slot, values, counter):

    >>> from canfdi.bus.e2e import protect
    >>> from canfdi.core.settings import BusConfig, MonitorConfig
    >>> config = MonitorConfig.of_bus("dc_motor", ["V"], ["i_f", "i_a", "i_f_plus_i_a", "omega_r"],
    ...                               BusConfig(dbc="motor_drive"))
    >>> bus_map = BusMap.from_config(config)
    >>> bus_map
    BusMap(dc_motor: motor_drive: DRIVE_CMD=0x104, DRIVE_CURRENTS=0x105, DRIVE_SPEED=0x106; \
p=1, q=4)
    >>> speed = protect(0x106, bytes(2) + (1234).to_bytes(2, "little"), 7)
    >>> bus_map.decode_frame(0x106, speed)
    ('ok', 2, (12.34,), 7)
    >>> bus_map.decode_frame(0x106, bytes([speed[0] ^ 1]) + speed[1:])[0]
    'crc'
    """

    def __init__(self, dbc_label: str, drive: str, input_names: Sequence[str],
                 output_names: Sequence[str], slots: Sequence[_Slot],
                 others: Mapping[MessageKey, Known] | None = None,
                 trigger_slot: int | None = None) -> None:
        self.dbc_label = dbc_label
        self.drive = drive
        self.input_names = tuple(input_names)
        self.output_names = tuple(output_names)
        self._slots = tuple(slots)
        self.layouts = tuple(s.layout for s in self._slots)
        self.fields = tuple(s.fields for s in self._slots)
        self.keys = tuple(s.key for s in self._slots)
        self.e2e = tuple(s.e2e for s in self._slots)
        self._dests = tuple(s.dests for s in self._slots)
        self.slot_of = {s.key: i for i, s in enumerate(self._slots)}
        self.trigger_slot = trigger_slot
        moduli = {s.e2e.counter_modulus for s in self._slots}
        self.counter_modulus = moduli.pop() if len(moduli) == 1 else None
        self.n_signals_max = max((len(f) for f in self.fields), default=0)
        others = {k: v for k, v in (others or {}).items() if k not in self.slot_of}
        self.monitor_keys = frozenset(k for k, v in others.items() if v.kind == "monitor")
        self.unused_keys = frozenset(k for k, v in others.items() if v.kind == "unused")
        # Every known message is an entry: the slots first (entry = slot), then the others.
        entries = [Known("ok", s.layout.dlc, bool(getattr(s.layout, "is_fd", False)), s.e2e)
                   for s in self._slots] + list(others.values())
        keys = list(self.keys) + list(others)
        self._entries = entries
        self._entry_of = {key: e for e, key in enumerate(keys)}
        self._kind = np.array([STATUS_CODES[k.kind] for k in entries], dtype=np.int8)
        self._length = np.array([k.length for k in entries], dtype=np.int64)
        self._is_fd = np.array([k.fd for k in entries], dtype=bool)
        # Dense table over the 11-bit ID space (the common case), a sorted array for 29-bit.
        self._entry_table = np.full(MAX_STANDARD_ID + 1, -1, dtype=np.int32)
        ext = sorted((key[0], e) for key, e in self._entry_of.items() if key[1])
        for (fid, extended), e in self._entry_of.items():
            if not extended:
                self._entry_table[fid] = e
        self._ext_ids = np.array([fid for fid, _ in ext], dtype=np.int64)
        self._ext_entry = np.array([e for _, e in ext], dtype=np.int32)
        self._c_tables: BusTables | None = None
        self.decoder: Callable[[BusMap, FrameBlock], tuple] = BusMap.decode_frames_reference

    @property
    def p(self) -> int:
        """Number of model inputs."""
        return len(self.input_names)

    @property
    def q(self) -> int:
        """Number of model outputs."""
        return len(self.output_names)

    def model_signals(self) -> tuple[list[SignalLayout], list[SignalLayout]]:
        """The DBC signal layout of each model input (p,) and output (q,), in model order."""
        u: list = [None] * self.p
        z: list = [None] * self.q
        for layout, fields in zip(self.layouts, self.fields, strict=True):
            for name, vec, j in fields:
                (u if vec == "u" else z)[j] = layout.signal(name)
        return u, z

    def quantize(self, U: np.ndarray, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(..., p) commands and (..., q) measurements as the monitor receives them: each value
        through its signal's encode and decode (`SignalLayout.quantize`), and NaN for every
        value of a message one of whose values the encoding clipped (its frame "saturated",
        as `decode_frames` finds it)."""
        u_sig, z_sig = self.model_signals()
        flat = np.empty((*np.shape(U)[:-1], self.p + self.q))
        for j, sig in enumerate(u_sig):
            flat[..., j] = sig.quantize(U[..., j])
        for j, sig in enumerate(z_sig):
            flat[..., self.p + j] = sig.quantize(Z[..., j])
        for s in self._slots:
            if s.dests:
                dests = list(s.dests)
                values = flat[..., dests]
                values[s.saturated(values)] = np.nan
                flat[..., dests] = values
        return flat[..., :self.p], flat[..., self.p:]

    def resolution(self, U: np.ndarray, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """((p,), (q,)): the rounding noise each model input and output carries on the bus
        (`SignalLayout.resolution_std` over the values U (N, p), Z (N, q))."""
        u_sig, z_sig = self.model_signals()
        return (np.array([s.resolution_std(U[:, j]) for j, s in enumerate(u_sig)]),
                np.array([s.resolution_std(Z[:, j]) for j, s in enumerate(z_sig)]))

    def __repr__(self) -> str:
        used = ", ".join(f"{lay.name}=0x{key[0]:X}" for lay, key in zip(self.layouts, self.keys,
                                                                        strict=True))
        return f"BusMap({self.drive}: {self.dbc_label}: {used}; p={self.p}, q={self.q})"

    # -- construction -------------------------------------------------------------------------

    @classmethod
    def from_config(cls, config: MonitorConfig, drive: DriveConfig | None = None,
                    monitor: Mapping[MessageKey, Known] | None = None) -> BusMap:
        """Compile ``drive`` (default: the config's first) from the config's bus section.

        ``monitor``: the monitor's own frames (canfdi.bus.monitorframes), known as "monitor".

        Raises
        ------
        ConfigError
            Naming the field: ``bus.dbc`` (none, not found, not loadable), ``bus.map.<name>``
            (no such message or signal, with the nearest names), ``bus.e2e...`` (a profile its
            message cannot take), ``bus.clock.message``, ``bus.node.id`` (an ID out of range).
        """
        bus = config.bus
        if bus.dbc is None:
            raise ConfigError("bus.dbc", "a DBC file is needed to read the bus")
        database, label = load_dbc(bus.dbc, config.path)
        drive = drive or config.drive_list[0]
        return cls.from_dbc(database, config, drive, label, monitor)

    @classmethod
    def from_dbc(cls, database: Database, config: MonitorConfig, drive: DriveConfig,
                 dbc_label: str, monitor: Mapping[MessageKey, Known] | None = None) -> BusMap:
        """`from_config` with the DBC already loaded. Every message of the DBC, on every drive
        of the config, that is not this drive's slot is known as "unused"."""
        bus = config.bus
        for i, ref in enumerate(bus.node_shared):
            find_message(database, ref, f"bus.node.shared[{i}]", dbc_label)
        p = len(config.inputs)
        model_names = {"u": config.inputs, "z": config.outputs}
        by_message: dict[str, tuple[Message, list[tuple[str, str, int]]]] = {}
        for vector, names in (("u", config.inputs), ("z", config.outputs)):
            for j, name in enumerate(names):
                message, signal = _resolve(database, name, bus.map.get(name), dbc_label)
                entry = by_message.setdefault(message.name, (message, []))
                entry[1].append((signal, vector, j))
        trigger: Message | None = None
        if bus.clock.kind == "trigger":
            trigger = find_message(database, bus.clock.message, "bus.clock.message", dbc_label)
            by_message.setdefault(trigger.name, (trigger, []))
        slots = []
        for message, fields in sorted(by_message.values(),
                                      key=lambda e: (e[0].is_extended_frame, e[0].frame_id)):
            key = _drive_key(bus, message, drive)
            check_no_overlap(message, [f[0] for f in fields], "bus.dbc", dbc_label)
            try:
                layout = compile_layout(message, [f[0] for f in fields])
            except ValueError as exc:
                raise ConfigError("bus.dbc", f"{dbc_label}: {exc}") from None
            profile = _profile(bus.e2e, message, key, explicit_only=False)
            # Values come out in the order of the payload.
            ordered = tuple(sorted(fields, key=lambda f, lay=layout: lay.signal(f[0]).start))
            dests = tuple(j if vec == "u" else p + j for _, vec, j in ordered)
            ranges = [_plausible(message, sig, bus.map.get(model_names[vec][j]))
                      for sig, vec, j in ordered]
            low = tuple(r[0] for r in ranges)
            high = tuple(r[1] for r in ranges)
            clips = [_clip_limits(layout.signal(sig)) for sig, _, _ in ordered]
            slots.append(_Slot(layout, key, profile, ordered, dests, _program(layout, ordered),
                               low, high, any(np.isfinite(low + high)),
                               tuple(c[0] for c in clips), tuple(c[1] for c in clips)))
        keys = [s.key for s in slots]
        if len(set(keys)) != len(keys):
            raise ConfigError("bus.node.id", f"two mapped messages of drive {drive.name} get "
                                             "the same ID")
        others: dict[MessageKey, Known] = {}
        for other in [*config.drive_list, None]:
            for message in database.messages:
                key = (_drive_key(bus, message, other) if other is not None
                       else message_key(message.frame_id, message.is_extended_frame))
                if key not in others:
                    others[key] = Known("unused", message.length, message.is_fd,
                                        _profile(bus.e2e, message, key, explicit_only=True))
        others.update(monitor or {})
        trigger_slot = (keys.index(_drive_key(bus, trigger, drive))
                        if trigger is not None else None)
        return cls(dbc_label, drive.name, config.inputs, config.outputs, slots, others,
                   trigger_slot)

    # -- decoding -----------------------------------------------------------------------------

    def decode_frame(self, frame_id: int, data: bytes | bytearray, flags: int = 0
                     ) -> tuple[str, int, tuple[float, ...], int]:
        """Check and decode one frame.

        Returns
        -------
        status : a name of canfdi.bus.frames' ``STATUS_NAMES``.
        slot : the message's slot (also when "dlc", "crc" or "fd"), else -1.
        values : for "ok", the physical values of ``fields[slot]`` in that order; else ().
        counter : the E2E alive counter of an "ok" frame (-1 without one).
        """
        if flags & FLAG_ERROR:
            return "error_frame", -1, (), -1
        extended = bool(flags & FLAG_EXTENDED)
        e = self._entry_of.get((frame_id, extended))
        if flags & FLAG_REMOTE:  # a request: known traffic (polling) when for a known message
            return ("remote" if e is None else "unused"), -1, (), -1
        if e is None:
            return ("fd" if flags & FLAG_FD else "extended" if extended else "unknown_id",
                    -1, (), -1)
        known = self._entries[e]
        slot = e if e < len(self._slots) else -1
        if bool(flags & FLAG_FD) != known.fd:
            return "fd", slot, (), -1
        if len(data) != known.length:
            return "dlc", slot, (), -1
        if not known.e2e.check(bytes(data)):
            return "crc", slot, (), -1
        if slot < 0:
            return known.kind, -1, (), -1
        s = self._slots[slot]
        counter = s.e2e.counter(bytes(data))
        counter = -1 if counter is None else counter
        if s.program is not None:
            values = _run_program(s.program, data)
        else:
            row = np.frombuffer(bytes(data), dtype=np.uint8)[None, :]
            decoded = s.layout.decode(row)
            values = tuple(float(decoded[name][0]) for name, _, _ in s.fields)
        if s.checked and not all(lo <= v <= hi for v, lo, hi in zip(values, s.low, s.high,
                                                                    strict=True)):
            return "implausible", slot, (), -1
        if any(v <= lo or v >= hi for v, lo, hi in zip(values, s.clip_low, s.clip_high,
                                                       strict=True)):
            return "saturated", slot, (), -1
        return "ok", slot, values, counter

    def c_tables(self) -> BusTables:
        """This map as the C core's tables (canfdi.bus.ctables), built once."""
        if self._c_tables is None:
            slots = [SlotSpec(s.layout, tuple(name for name, _, _ in s.fields), s.low, s.high,
                              s.clip_low, s.clip_high, s.checked) for s in self._slots]
            entries = [EntrySpec(STATUS_CODES[k.kind], k.length, k.fd, k.e2e)
                       for k in self._entries]
            self._c_tables = build_tables(entries, slots, self._entry_of, self.n_signals_max)
        return self._c_tables

    def decode_frames(
        self, block: FrameBlock
    ) -> tuple[NDArray[np.int8], NDArray[np.int16], NDArray[np.float64], NDArray[np.int64]]:
        """`decode_frame` for a whole block at once, on the kernel installed (``decoder``:
        `decode_frames_reference` unless canfdi.core.kernel installed another, which gives
        the same arrays)."""
        return self.decoder(self, block)

    def decode_frames_reference(
        self, block: FrameBlock
    ) -> tuple[NDArray[np.int8], NDArray[np.int16], NDArray[np.float64], NDArray[np.int64]]:
        """`decode_frame` for a whole block at once, in numpy (the reference).

        Returns
        -------
        status : (N,) int8 codes into ``STATUS_NAMES``.
        slot : (N,) int16, as for `decode_frame` (-1 when not a slot's message).
        values : (N, n_signals_max) float64; row i holds ``fields[slot[i]]``'s values for "ok"
            frames, NaN elsewhere.
        counters : (N,) int64, the E2E alive counter of "ok" frames, -1 elsewhere.
        """
        ids, dlc, flags = block.id.astype(np.int64), block.dlc, block.flags
        n = block.size
        extended = (flags & FLAG_EXTENDED) != 0
        standard = ~extended & (ids <= MAX_STANDARD_ID)
        entry = np.where(standard, self._entry_table[np.where(standard, ids, 0)], -1)
        if extended.any() and len(self._ext_ids):
            rows = np.flatnonzero(extended)
            pos = np.clip(np.searchsorted(self._ext_ids, ids[rows]), 0, len(self._ext_ids) - 1)
            hit = self._ext_ids[pos] == ids[rows]
            entry[rows[hit]] = self._ext_entry[pos[hit]]
        known = entry >= 0
        e = np.maximum(entry, 0)
        is_fd = (flags & FLAG_FD) != 0
        # int8 throughout: Python ints in np.where would make an int64 temporary.
        status = np.where(known, self._kind[e],
                          np.where(extended, np.int8(_EXTENDED), np.int8(_UNKNOWN_ID)))
        status[is_fd & (~known | (is_fd != self._is_fd[e]))] = _FD
        status[known & ~is_fd & self._is_fd[e]] = _FD
        status[known & (status != _FD) & (dlc != self._length[e])] = _DLC
        slot = np.where(known & (entry < len(self._slots)), entry, -1).astype(np.int16)
        blocked = (flags & (FLAG_REMOTE | FLAG_ERROR)) != 0
        remote = (flags & FLAG_REMOTE) != 0
        status[remote] = np.where(known[remote], _UNUSED, _REMOTE)
        status[(flags & FLAG_ERROR) != 0] = _ERROR
        slot[blocked] = -1
        values = np.full((n, self.n_signals_max), np.nan)
        counters = np.full(n, -1, dtype=np.int64)
        checked = known & ~blocked & (status != _FD) & (status != _DLC)
        present = np.bincount(entry[checked], minlength=len(self._entries))
        for ent in np.flatnonzero(present).tolist():
            rows = np.flatnonzero(checked & (entry == ent))
            item = self._entries[ent]
            payloads = block.payload_matrix(rows, item.length)
            ok = item.e2e.check_batch(payloads, dlc[rows].astype(np.int64))
            if not ok.all():  # (all pass, the usual case: no copy of the rows)
                status[rows[~ok]] = _CRC
                rows, payloads = rows[ok], payloads[ok]
            if ent >= len(self._slots) or not rows.size:
                continue
            s = self._slots[ent]
            decoded = s.layout.decode(payloads)
            for col, (name, _, _) in enumerate(s.fields):
                values[rows, col] = decoded[name]
            found = s.e2e.counters(payloads)
            if found is not None:
                counters[rows] = found
            if s.checked:
                width = len(s.fields)
                inside = ((values[rows, :width] >= np.array(s.low))
                          & (values[rows, :width] <= np.array(s.high))).all(axis=1)
                if not inside.all():
                    bad = rows[~inside]
                    status[bad] = _IMPLAUSIBLE
                    values[bad] = np.nan
                    counters[bad] = -1
            if s.fields:
                clipped = s.saturated(values[rows, :len(s.fields)])
                if clipped.any():
                    bad = rows[clipped]
                    status[bad] = _SATURATED
                    values[bad] = np.nan
                    counters[bad] = -1
        return status, slot, values, counters


_NAMES = {code: name for name, code in STATUS_CODES.items()}


def _run_program(program: tuple, data: bytes | bytearray) -> tuple[float, ...]:
    # A payload shorter than 8 bytes reads as if zero-padded: from_bytes needs no padding.
    word = int.from_bytes(data, "little")
    values = []
    for start, mask, sign, scale, offset, is_float in program:
        raw = (word >> start) & mask
        if is_float:
            values.append(_F32.unpack(raw.to_bytes(4, "little"))[0] * scale + offset)
            continue
        if raw & sign:
            raw -= sign << 1
        values.append(raw * scale + offset)
    return tuple(values)


def _drive_key(bus: BusConfig, message: Message, drive: DriveConfig) -> MessageKey:
    """The message's (ID, extended) on this drive (the node-id template applied, unless the
    message is one of the bus's shared ones)."""
    if message.name in bus.node_shared or message.frame_id in bus.node_shared:
        return message_key(message.frame_id, message.is_extended_frame)
    try:
        fid = frame_id(bus.node_id, message.frame_id, drive.node)
    except ValueError as exc:
        raise ConfigError("bus.node.id", f"{message.name}: {exc}") from None
    if not message.is_extended_frame and fid > MAX_STANDARD_ID:
        raise ConfigError("bus.node.id", f"{message.name} on node {drive.node}: 0x{fid:X} is "
                                         "not an 11-bit ID")
    return message_key(fid, message.is_extended_frame)


def keys_of(database: Database, config: MonitorConfig) -> set[MessageKey]:
    """Every message of the DBC on every drive of the config (and as the DBC writes it)."""
    out = {message_key(m.frame_id, m.is_extended_frame) for m in database.messages}
    for drive in config.drive_list:
        out |= {_drive_key(config.bus, m, drive) for m in database.messages}
    return out
