"""The DBC side of the bus: which messages carry the model's inputs and outputs, compiled once.

`BusMap` compiles the drive's DBC (canfdi.bus.codec layouts): which drive messages carry the
model's inputs u and outputs z, where each signal sits in the payload, the CRC register after
each message's Data ID, and which IDs are the monitor's own ``FDI_*`` frames. `BusMap.decode_frame`
checks and decodes one frame with integer shifts and masks (no cantools on the hot path);
`BusMap.decode_frames` does a whole `FrameBlock` with numpy. The frame statuses it gives are
those of canfdi.bus.frames (``STATUS_NAMES``).
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from canfdi.bus.codec import MessageLayout, SignalLayout, compile_layout
from canfdi.bus.e2e import CRC8_XOROUT, crc8, data_id, e2e_check_batch
from canfdi.bus.frames import STATUS_CODES, STATUS_NAMES, FrameBlock
from canfdi.core.settings import ConfigError, MonitorConfig

if TYPE_CHECKING:
    from cantools.database.can import Database

__all__ = ["BusMap", "load_dbc"]

_OK, _MONITOR, _UNUSED = STATUS_CODES["ok"], STATUS_CODES["monitor"], STATUS_CODES["unused"]
_UNKNOWN_ID, _DLC, _CRC = STATUS_CODES["unknown_id"], STATUS_CODES["dlc"], STATUS_CODES["crc"]
# Message kinds in the ID table; their codes double as the valid frame statuses.
_KIND_DRIVE, _KIND_MONITOR, _KIND_UNUSED = _OK, _MONITOR, _UNUSED

_E2E_HEADER = {"CRC": (0, 8), "Counter": (8, 8)}
_MAX_STD_ID = 0x7FF
_F32 = struct.Struct("<f")


def _has_e2e_header(layout: MessageLayout) -> bool:
    found = {sig.name: (sig.start, sig.length) for sig in layout.signals}
    return all(found.get(name) == place for name, place in _E2E_HEADER.items())


def _in_word_program(sig: SignalLayout, dlc: int) -> bool:
    """Whether `BusMap.decode_frame`'s shift-and-mask program reads ``sig`` as the codec does:
    an Intel integer, or an unscaled float32, within an 8-byte payload, not multiplexed."""
    return (sig.byte_order == "little_endian" and sig.multiplexer_signal is None and dlc <= 8
            and sig.start + sig.length <= 64
            and (not sig.is_float or (sig.length == 32 and sig.scale == 1 and sig.offset == 0)))


def _crc_seed(frame_id: int) -> int:
    # The CRC register after the Data ID is a constant of the ID: precompute it so a frame's
    # check only runs over its own payload bytes (crc8 returns the register XOR-ed out).
    return crc8(data_id(frame_id)) ^ CRC8_XOROUT


class BusMap:
    """Where the model's inputs and outputs are on the bus, compiled from a DBC.

    Build it with `from_config` or `from_dbc`. Attributes (read-only by convention):

    dbc_label : str, the DBC's name or path, for messages.
    input_names, output_names : (p,), (q,) model signal names, in the model's order.
    layouts : (M,) compiled layouts of the used drive messages (those carrying at least one
        model signal), in ascending ID order; a message's position is its *slot*.
    slot_of : frame_id -> (slot, dlc) of the used drive messages.
    fields : (M,) per slot, the (signal, vector 'u' or 'z', index) triples of its model
        signals, in the order of the values `decode_frame` returns.
    monitor_layouts : compiled layouts of the messages sent by FDI (the monitor's own frames).
    monitor_ids : their IDs.
    unused_ids : IDs of the other DBC messages (drive messages with no model signal, ...).
    n_signals_max : width of the values array of `decode_frames` (most fields in one slot).
    """

    def __init__(
        self,
        dbc_label: str,
        input_names: Sequence[str],
        output_names: Sequence[str],
        layouts: Sequence[MessageLayout],
        fields: Sequence[Sequence[tuple[str, str, int]]],
        monitor_layouts: Sequence[MessageLayout],
        unused_layouts: Sequence[MessageLayout],
    ) -> None:
        self.dbc_label = dbc_label
        self.input_names = tuple(input_names)
        self.output_names = tuple(output_names)
        self.layouts = tuple(layouts)
        self.fields = tuple(tuple(f) for f in fields)
        if len(self.fields) != len(self.layouts):
            raise ValueError(f"fields: one entry per layout expected ({len(self.layouts)}), "
                             f"got {len(self.fields)}")
        self.slot_of = {lay.frame_id: (slot, lay.dlc) for slot, lay in enumerate(self.layouts)}
        self.monitor_layouts = tuple(monitor_layouts)
        self.monitor_ids = frozenset(lay.frame_id for lay in monitor_layouts)
        self.unused_ids = frozenset(lay.frame_id for lay in unused_layouts)
        self.n_signals_max = max((len(f) for f in self.fields), default=0)
        p = len(self.input_names)
        # Each slot's values land at these positions of the flat [u, z] buffer.
        self._dests = tuple(tuple(j if vec == "u" else p + j for _, vec, j in f)
                            for f in self.fields)
        # One look-up per frame: id -> (kind, slot, dlc, crc seed or -1, decode program).
        entries: dict[int, tuple] = {}
        kinds = ((_KIND_MONITOR, monitor_layouts), (_KIND_UNUSED, unused_layouts))
        for kind, group in kinds:
            for lay in group:
                seed = _crc_seed(lay.frame_id) if _has_e2e_header(lay) else -1
                entries[lay.frame_id] = (kind, -1, lay.dlc, seed, ())
        for slot, (lay, f) in enumerate(zip(self.layouts, self.fields, strict=True)):
            program: tuple | None = []
            for name, _, _ in f:
                sig = lay.signal(name)
                if not _in_word_program(sig, lay.dlc):
                    program = None  # decode_frame goes through the layout's decode
                    break
                sign = 1 << (sig.length - 1) if sig.signed and not sig.is_float else 0
                program.append((sig.start, sig.mask, sign, sig.scale, sig.offset, sig.is_float))
            entries[lay.frame_id] = (_KIND_DRIVE, slot, lay.dlc, _crc_seed(lay.frame_id),
                                     None if program is None else tuple(program))
        self._entries = entries
        # Dense tables over the 11-bit ID space for the vectorised decode.
        self._kind_table = np.full(_MAX_STD_ID + 1, _UNKNOWN_ID, dtype=np.int8)
        self._slot_table = np.full(_MAX_STD_ID + 1, -1, dtype=np.int16)
        self._dlc_table = np.full(_MAX_STD_ID + 1, -1, dtype=np.int16)
        self._protected_table = np.zeros(_MAX_STD_ID + 1, dtype=bool)
        for frame_id, (kind, slot, dlc, seed, _) in entries.items():
            self._kind_table[frame_id] = kind
            self._slot_table[frame_id] = slot
            self._dlc_table[frame_id] = dlc
            self._protected_table[frame_id] = seed >= 0

    @property
    def p(self) -> int:
        """Number of model inputs."""
        return len(self.input_names)

    @property
    def q(self) -> int:
        """Number of model outputs."""
        return len(self.output_names)

    def __repr__(self) -> str:
        used = ", ".join(f"{lay.name}=0x{lay.frame_id:X}" for lay in self.layouts)
        return f"BusMap({self.dbc_label}: {used}; p={self.p}, q={self.q})"

    def model_signals(self) -> tuple[list[SignalLayout], list[SignalLayout]]:
        """The DBC signal layout of each model input (p,) and output (q,), in model order."""
        u: list = [None] * self.p
        z: list = [None] * self.q
        for layout, fields in zip(self.layouts, self.fields, strict=True):
            for name, vec, j in fields:
                (u if vec == "u" else z)[j] = layout.signal(name)
        return u, z

    def quantize(self, U: np.ndarray, Z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(..., p) commands and (..., q) measurements as the bus carries them: each value
        through its signal's encode and decode (`SignalLayout.quantize`)."""
        u_sig, z_sig = self.model_signals()
        U_q, Z_q = np.empty_like(U, dtype=float), np.empty_like(Z, dtype=float)
        for j, sig in enumerate(u_sig):
            U_q[..., j] = sig.quantize(U[..., j])
        for j, sig in enumerate(z_sig):
            Z_q[..., j] = sig.quantize(Z[..., j])
        return U_q, Z_q

    # -- construction -------------------------------------------------------------------------

    @classmethod
    def from_config(cls, config: MonitorConfig) -> BusMap:
        """Load ``config.bus.dbc`` and map ``config.inputs`` and ``config.outputs`` onto it.

        ``bus.dbc`` is the name of a DBC shipped in ``canfdi.dbc`` (``motor_drive``) or a path
        to a DBC file, relative to the config file's directory (or the working directory when
        the config has no path).

        Raises
        ------
        ConfigError
            ``bus.dbc`` when no DBC is configured, it cannot be found or loaded, or a drive
            message lacks the E2E header; ``signals.inputs[i]`` / ``signals.outputs[j]`` when a
            name is in no DRIVE message, or in more than one.
        """
        value = config.bus.dbc
        if value is None:
            raise ConfigError("bus.dbc", "a DBC file is needed to read the bus")
        database, label = load_dbc(value, config.path)
        return cls.from_dbc(database, config.inputs, config.outputs, label)

    @classmethod
    def from_dbc(
        cls,
        database: Database,
        input_names: Sequence[str],
        output_names: Sequence[str],
        dbc_label: str,
    ) -> BusMap:
        """Map model signal names onto a loaded cantools database.

        Parameters
        ----------
        database : cantools CAN database (e.g. ``canfdi.dbc.load("motor_drive")``).
        input_names : (p,) names of the model inputs u, each a signal of exactly one message
            sent by DRIVE.
        output_names : (q,) names of the model outputs z, likewise.
        dbc_label : how to name the database in error messages (its name or path).

        Returns
        -------
        BusMap

        Raises
        ------
        ConfigError
            As for `from_config`.
        """
        drive, monitor, unused = [], [], []
        for message in sorted(database.messages, key=lambda m: m.frame_id):
            senders = message.senders or []
            try:
                layout = compile_layout(message)
            except ValueError as exc:
                if "DRIVE" in senders or "FDI" in senders:
                    raise ConfigError("bus.dbc", f"{dbc_label}: {exc}") from None
                # A message of no interest: its ID and length are all that is needed.
                layout = compile_layout(message, signals=())
            if "DRIVE" in senders:
                drive.append(layout)
            elif "FDI" in senders:
                monitor.append(layout)
            else:
                unused.append(layout)
        where: dict[str, list[MessageLayout]] = {}
        for layout in drive:
            for sig in layout.signals:
                if sig.name not in _E2E_HEADER:
                    where.setdefault(sig.name, []).append(layout)
        fields: dict[int, list[tuple[str, str, int]]] = {}
        for vector, names, key in (("u", input_names, "inputs"), ("z", output_names, "outputs")):
            for j, name in enumerate(names):
                field = f"signals.{key}[{j}]"
                found = where.get(name, [])
                if name in _E2E_HEADER:
                    raise ConfigError(field, f"'{name}' is the E2E header of every message of "
                                             f"{dbc_label}, not a model signal")
                if not found:
                    raise ConfigError(field, f"no signal '{name}' in any DRIVE message of "
                                             f"{dbc_label}")
                if len(found) > 1:
                    names_found = ", ".join(lay.name for lay in found)
                    raise ConfigError(field, f"signal '{name}' is in {len(found)} DRIVE messages "
                                             f"of {dbc_label} ({names_found}); it must be in "
                                             "exactly one")
                fields.setdefault(found[0].frame_id, []).append((name, vector, j))
        used = [lay for lay in drive if lay.frame_id in fields]
        for layout in used:
            if not _has_e2e_header(layout):
                raise ConfigError("bus.dbc", f"{dbc_label}: {layout.name} has no E2E header "
                                             "(CRC at bits 0|8, Counter at 8|8); samples cannot "
                                             "be assembled without it")
        # Sorted by payload position so that values come out in the order of the message.
        ordered = [sorted(fields[lay.frame_id], key=lambda f, lay=lay: lay.signal(f[0]).start)
                   for lay in used]
        unused += [lay for lay in drive if lay.frame_id not in fields]
        return cls(dbc_label, input_names, output_names, used, ordered, monitor, unused)

    # -- decoding -----------------------------------------------------------------------------

    def decode_frame(
        self, frame_id: int, data: bytes | bytearray
    ) -> tuple[str, int, tuple[float, ...]]:
        """Check and decode one classic 11-bit data frame.

        Parameters
        ----------
        frame_id : arbitration ID.
        data : (dlc,) payload.

        Returns
        -------
        status : "ok", "monitor", "unused", "unknown_id", "dlc" or "crc".
        slot : the message's slot for frames of a used drive message (also when "dlc" or
            "crc"), else -1.
        values : for "ok", the physical values of ``fields[slot]`` in that order; else ().
        """
        entry = self._entries.get(frame_id)
        if entry is None:
            return "unknown_id", -1, ()
        kind, slot, dlc, seed, program = entry
        if len(data) != dlc:
            return "dlc", slot, ()
        if seed >= 0 and crc8(data[1:], seed) != data[0]:
            return "crc", slot, ()
        if kind != _KIND_DRIVE:
            return STATUS_NAMES[kind], -1, ()
        if program is None:
            decoded = self.layouts[slot].decode(np.frombuffer(bytes(data), np.uint8)[None, :])
            return "ok", slot, tuple(float(decoded[name][0]) for name, _, _ in self.fields[slot])
        # A payload shorter than 8 bytes reads as if zero-padded: from_bytes needs no padding.
        word = int.from_bytes(data, "little")
        values = []
        for start, mask, sign, scale, offset, is_float in program:
            raw = (word >> start) & mask
            if is_float:
                values.append(_F32.unpack(raw.to_bytes(4, "little"))[0])
                continue
            if raw & sign:
                raw -= sign << 1
            values.append(raw * scale + offset)
        return "ok", slot, tuple(values)

    def decode_frames(
        self, block: FrameBlock
    ) -> tuple[NDArray[np.int8], NDArray[np.int16], NDArray[np.float64], NDArray[np.int16]]:
        """`decode_frame` for a whole block at once (all frames taken as classic 11-bit data:
        the flags are the assembler's business).

        Parameters
        ----------
        block : the frames; IDs above 0x7FF are "unknown_id", payloads zero- or garbage-padded
            beyond each frame's DLC.

        Returns
        -------
        status : (N,) int8 codes into `STATUS_NAMES` (ok, monitor, unused, unknown_id, dlc,
            crc).
        slot : (N,) int16, as for `decode_frame` (-1 when not a used drive message).
        values : (N, n_signals_max) float64; row i holds ``fields[slot[i]]``'s values for "ok"
            frames, NaN elsewhere.
        counters : (N,) int16, byte 1 of frames with a payload of 2 bytes or more, else -1.
        """
        ids, dlc, payloads = block.id, block.dlc, block.data
        n = block.size
        known_id = ids <= _MAX_STD_ID
        lookup = np.where(known_id, ids, 0).astype(np.intp)
        kind = np.where(known_id, self._kind_table[lookup], _UNKNOWN_ID).astype(np.int8)
        slot = np.where(known_id, self._slot_table[lookup], -1).astype(np.int16)
        status = kind.copy()
        known = kind != _UNKNOWN_ID
        bad_dlc = known & (dlc != self._dlc_table[lookup])
        status[bad_dlc] = _DLC
        check = known & ~bad_dlc & self._protected_table[lookup]
        rows = np.flatnonzero(check)
        if rows.size:
            crc_ok = e2e_check_batch(ids[rows], payloads[rows], dlc[rows])
            status[rows[~crc_ok]] = _CRC
        values = np.full((n, self.n_signals_max), np.nan)
        for s, (layout, f) in enumerate(zip(self.layouts, self.fields, strict=True)):
            rows = np.flatnonzero((status == _OK) & (slot == s))
            if rows.size:
                decoded = layout.decode(payloads[rows])
                for col, (name, _, _) in enumerate(f):
                    values[rows, col] = decoded[name]
        counters = np.where(dlc >= 2, payloads[:, 1].astype(np.int16), np.int16(-1))
        return status, slot, values, counters


def load_dbc(value: str, config_path: Path | None) -> tuple[Database, str]:
    """The database named or pointed to by ``bus.dbc``, and a label for messages."""
    import cantools

    from canfdi import dbc as dbc_files

    if Path(value).name == value and value.removesuffix(".dbc") in dbc_files.available():
        return dbc_files.load(value), value.removesuffix(".dbc")
    candidate = Path(value).expanduser()
    if not candidate.is_absolute() and config_path is not None:
        candidate = Path(config_path).parent / candidate
    if not candidate.is_file():
        shipped = ", ".join(dbc_files.available()) or "none"
        raise ConfigError("bus.dbc", f"no DBC file {candidate} and no shipped DBC named "
                                     f"{value!r} (shipped: {shipped})")
    try:
        database = cantools.database.load_file(candidate, database_format="dbc", strict=True)
    except (OSError, ValueError, cantools.database.Error) as exc:
        raise ConfigError("bus.dbc", f"cannot load {candidate}: {exc}") from None
    return database, str(candidate)  # type: ignore[return-value]


