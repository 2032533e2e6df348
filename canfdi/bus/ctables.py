"""A drive's bus map as the C core's flat tables (canfdi/_c/decode.h), and the monitor's own
messages as the tables it encodes them from (canfdi/_c/encode.h): the one place in Python that
knows their layout.

`BusTables` holds the arrays `cfdi_decode_block` reads: which entry each ID is, each entry's
length, FD flag, E2E profile and compiled signals, each signal's place, conversion,
multiplexer and ranges. The extension decodes frames from them (canfdi.core.kernel) and
``canfdi codegen`` writes them as const data: tables, never logic.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from canfdi.bus.codec import MessageLayout, _float_at_least, _float_at_most
from canfdi.bus.e2e import E2EProfile

__all__ = ["DECODE_H", "ENCODE_H", "BusTables", "MessageTables", "build_tables",
           "message_tables"]

# decode.h's indices and sizes (a test reads them from the header and compares).
DECODE_H = {
    "CFDI_ENTRY_KIND": 0, "CFDI_ENTRY_LENGTH": 1, "CFDI_ENTRY_FD": 2, "CFDI_ENTRY_PROFILE": 3,
    "CFDI_ENTRY_SIG_AT": 4, "CFDI_ENTRY_SIG_COUNT": 5, "CFDI_ENTRY_COLUMNS": 6,
    "CFDI_ENTRY_CHECKED": 7, "CFDI_ENTRY_INTS": 8,
    "CFDI_SIG_START": 0, "CFDI_SIG_LENGTH": 1, "CFDI_SIG_FLAGS": 2, "CFDI_SIG_CONV": 3,
    "CFDI_SIG_ISCALE": 4, "CFDI_SIG_IOFFSET": 5, "CFDI_SIG_PARENT": 6, "CFDI_SIG_IDS_AT": 7,
    "CFDI_SIG_IDS_COUNT": 8, "CFDI_SIG_NUMBER": 9, "CFDI_SIG_COLUMN": 10, "CFDI_SIG_INTS": 11,
    "CFDI_SIGF_BIG": 1, "CFDI_SIGF_SIGNED": 2, "CFDI_SIGF_FLOAT": 4, "CFDI_SIGF_NEVER": 8,
    "CFDI_SIGF_MUX": 16,
    "CFDI_CONV_IDENTITY": 0, "CFDI_CONV_INTEGER": 1, "CFDI_CONV_INTEGER_FLOAT": 2,
    "CFDI_CONV_LINEAR": 3,
    "CFDI_NUM_INT": 0, "CFDI_NUM_UINT": 1, "CFDI_NUM_REAL": 2,
    "CFDI_SIG_SCALE": 0, "CFDI_SIG_OFFSET": 1, "CFDI_SIG_LOW": 2, "CFDI_SIG_HIGH": 3,
    "CFDI_SIG_CLIP_LOW": 4, "CFDI_SIG_CLIP_HIGH": 5, "CFDI_SIG_REALS": 6,
    "CFDI_SLOT_SIGNALS": 64, "CFDI_MAX_PAYLOAD": 64,
}
# encode.h's indices and sizes (a test reads them from the header and compares).
ENCODE_H = {
    "CFDI_ENC_START": 0, "CFDI_ENC_LENGTH": 1, "CFDI_ENC_FLAGS": 2, "CFDI_ENC_ROLE": 3,
    "CFDI_ENC_INTS": 4,
    "CFDI_ENC_SCALE": 0, "CFDI_ENC_OFFSET": 1, "CFDI_ENC_LO": 2, "CFDI_ENC_HI": 3,
    "CFDI_ENC_RAW_LO": 4, "CFDI_ENC_RAW_HI": 5, "CFDI_ENC_REALS": 6,
    "CFDI_ROLE_NONE": 0, "CFDI_ROLE_KIND": 1, "CFDI_ROLE_STATE": 2, "CFDI_ROLE_DRIVE": 3,
    "CFDI_ROLE_INDEX": 4, "CFDI_ROLE_SAMPLE": 5, "CFDI_ROLE_PARAM": 6, "CFDI_ROLE_VALUE": 7,
    "CFDI_ROLE_ACTIVE": 8, "CFDI_ROLE_INVALID": 9, "CFDI_N_ROLES": 10,
}
_H = DECODE_H
_CONV = {"identity": _H["CFDI_CONV_IDENTITY"], "integer": _H["CFDI_CONV_INTEGER"],
         "integer_float": _H["CFDI_CONV_INTEGER_FLOAT"], "linear": _H["CFDI_CONV_LINEAR"]}
_NUMBER = {"int": _H["CFDI_NUM_INT"], "uint": _H["CFDI_NUM_UINT"], "real": _H["CFDI_NUM_REAL"]}


@dataclass(frozen=True)
class SlotSpec:
    """What the tables need of one slot: its layout, its model fields in the order values
    come out, and each field's plausible range and clip limits (canfdi.bus.dbc._Slot)."""

    layout: MessageLayout
    fields: tuple[str, ...]
    low: tuple[float, ...]
    high: tuple[float, ...]
    clip_low: tuple[float, ...]
    clip_high: tuple[float, ...]
    checked: bool


@dataclass(frozen=True)
class EntrySpec:
    """One known message: the status its good frames get, its length, FD flag and profile."""

    kind: int
    length: int
    fd: bool
    e2e: E2EProfile


@dataclass(frozen=True)
class BusTables:
    """The arrays of a ``cfdi_bus`` (canfdi/_c/decode.h names each column), C-contiguous.

    std_id (N,) int64 ascending, std_entry (N,) int32: the 11-bit IDs and their entries; ext_id
    (X,) int64 ascending, ext_entry (X,) int32: the 29-bit ones; entry
    (E, CFDI_ENTRY_INTS) int64 with n_slots of them slots; e2e_spec (P, CFDI_E2E_INTS) int32,
    e2e_bytes (P, CFDI_E2E_BYTES) uint8; sig_int (S, CFDI_SIG_INTS) int64, sig_real
    (S, CFDI_SIG_REALS) float64; ids_int (I,) int64, ids_real (I,) float64; width: the values'
    columns.

    Examples
    --------
    The dc_motor drive's DRIVE_SPEED (slot 2): one signal, omega_r, 16 bits at bit 16, scale
    0.01, its value in column 0:

    >>> from canfdi.bus.dbc import BusMap
    >>> from canfdi.core.settings import BusConfig, MonitorConfig
    >>> config = MonitorConfig.of_bus("dc_motor", ["V"], ["i_f", "i_a", "i_f_plus_i_a", "omega_r"],
    ...                               BusConfig(dbc="motor_drive"))
    >>> t = BusMap.from_config(config).c_tables()
    >>> at = int(t.entry[2, DECODE_H["CFDI_ENTRY_SIG_AT"]])
    >>> sig = t.sig_int[at]
    >>> (int(sig[DECODE_H["CFDI_SIG_START"]]), int(sig[DECODE_H["CFDI_SIG_LENGTH"]]),
    ...  float(t.sig_real[at, DECODE_H["CFDI_SIG_SCALE"]]), int(sig[DECODE_H["CFDI_SIG_COLUMN"]]))
    (16, 16, 0.01, 0)
    >>> t.fits
    True
    """

    std_id: np.ndarray
    std_entry: np.ndarray
    ext_id: np.ndarray
    ext_entry: np.ndarray
    entry: np.ndarray
    n_slots: int
    e2e_spec: np.ndarray
    e2e_bytes: np.ndarray
    sig_int: np.ndarray
    sig_real: np.ndarray
    ids_int: np.ndarray
    ids_real: np.ndarray
    width: int

    @property
    def c_args(self) -> tuple:
        """The tables as canfdi._ckernel.decode_block takes them."""
        return (self.std_id, self.std_entry, len(self.std_id), self.ext_id, self.ext_entry,
                len(self.ext_id), self.entry,
                len(self.entry), self.n_slots, self.e2e_spec, self.e2e_bytes,
                len(self.e2e_spec), self.sig_int, self.sig_real, len(self.sig_int),
                self.ids_int, self.ids_real, len(self.ids_int), self.width)

    @property
    def fits(self) -> bool:
        """Whether every slot is within the C core's bounds (CFDI_SLOT_SIGNALS signals)."""
        count = self.entry[:, _H["CFDI_ENTRY_SIG_COUNT"]]
        return bool((count <= _H["CFDI_SLOT_SIGNALS"]).all())


def build_tables(entries: Sequence[EntrySpec], slots: Sequence[SlotSpec],
                 entry_of: dict[tuple[int, bool], int], width: int) -> BusTables:
    """The tables of a bus map: ``entries`` (the slots first, entry = slot), ``slots`` their
    layouts and fields, ``entry_of`` (ID, extended) -> entry, ``width`` the values' columns.

    Examples
    --------
    >>> from canfdi.bus.dbc import BusMap
    >>> from canfdi.core.settings import BusConfig, MonitorConfig
    >>> config = MonitorConfig.of_bus("dc_motor", ["V"], ["i_f", "i_a", "i_f_plus_i_a", "omega_r"],
    ...                               BusConfig(dbc="motor_drive"))
    >>> tables = BusMap.from_config(config).c_tables()
    >>> int(tables.std_entry[list(tables.std_id).index(0x105)]), tables.n_slots, tables.width
    (1, 3, 3)
    """
    std = sorted((fid, e) for (fid, extended), e in entry_of.items() if not extended)
    ext = sorted((fid, e) for (fid, extended), e in entry_of.items() if extended)
    profiles: list[tuple[np.ndarray, np.ndarray]] = []
    seen: dict[tuple[bytes, bytes], int] = {}
    entry = np.zeros((len(entries), _H["CFDI_ENTRY_INTS"]), dtype=np.int64)
    sig_int: list[list[int]] = []
    sig_real: list[list[float]] = []
    ids_int: list[int] = []
    ids_real: list[float] = []
    for e, known in enumerate(entries):
        spec, table = known.e2e.c_spec()
        key = (spec.tobytes(), table.tobytes())
        if key not in seen:
            seen[key] = len(profiles)
            profiles.append((spec, table))
        row = entry[e]
        row[_H["CFDI_ENTRY_KIND"]] = known.kind
        row[_H["CFDI_ENTRY_LENGTH"]] = known.length
        row[_H["CFDI_ENTRY_FD"]] = int(known.fd)
        row[_H["CFDI_ENTRY_PROFILE"]] = seen[key]
        row[_H["CFDI_ENTRY_SIG_AT"]] = len(sig_int)
        if e >= len(slots):
            continue
        slot = slots[e]
        plan = slot.layout.plan()
        column = {name: c for c, name in enumerate(slot.fields)}
        for item in plan:
            sig = item.signal
            c = column.get(sig.name, -1)
            flags = ((_H["CFDI_SIGF_BIG"] if sig.is_big_endian else 0)
                     | (_H["CFDI_SIGF_SIGNED"] if sig.signed and not sig.is_float else 0)
                     | (_H["CFDI_SIGF_FLOAT"] if sig.is_float else 0)
                     | (_H["CFDI_SIGF_NEVER"] if item.never else 0)
                     | (_H["CFDI_SIGF_MUX"] if sig.is_multiplexer else 0))
            parent_kind = plan[item.parent].number if item.parent >= 0 else "int"
            sig_int.append([sig.start, sig.length, flags, _CONV[item.conv], item.iscale,
                            item.ioffset, item.parent, len(ids_int), len(item.ids),
                            _NUMBER[item.number], c])
            for v in item.ids:
                if parent_kind == "real":
                    ids_int.append(0)
                    ids_real.append(float(v))
                else:
                    ids_int.append(int(np.array(v, dtype=np.uint64 if parent_kind == "uint"
                                                else np.int64).view(np.int64)))
                    ids_real.append(float(v))
            lo, hi, clo, chi = ((slot.low[c], slot.high[c], slot.clip_low[c], slot.clip_high[c])
                                if c >= 0 else (-math.inf, math.inf, -math.inf, math.inf))
            sig_real.append([sig.scale, sig.offset, lo, hi, clo, chi])
        row[_H["CFDI_ENTRY_SIG_COUNT"]] = len(plan)
        row[_H["CFDI_ENTRY_COLUMNS"]] = len(slot.fields)
        row[_H["CFDI_ENTRY_CHECKED"]] = int(slot.checked)
    return BusTables(
        std_id=np.array([fid for fid, _ in std], dtype=np.int64),
        std_entry=np.array([e for _, e in std], dtype=np.int32),
        ext_id=np.array([fid for fid, _ in ext], dtype=np.int64),
        ext_entry=np.array([e for _, e in ext], dtype=np.int32),
        entry=entry, n_slots=len(slots),
        e2e_spec=np.ascontiguousarray(np.array([p[0] for p in profiles], dtype=np.int32)),
        e2e_bytes=np.ascontiguousarray(np.array([p[1] for p in profiles], dtype=np.uint8)),
        sig_int=np.array(sig_int, dtype=np.int64).reshape(-1, _H["CFDI_SIG_INTS"]),
        sig_real=np.array(sig_real, dtype=np.float64).reshape(-1, _H["CFDI_SIG_REALS"]),
        ids_int=np.array(ids_int, dtype=np.int64), ids_real=np.array(ids_real),
        width=width)


@dataclass(frozen=True)
class MessageTables:
    """A monitor message as cfdi_encode reads it (encode.h's cfdi_message): its ID, length,
    E2E profile (e2e.h's two rows) and signals, (n, CFDI_ENC_INTS) int64 and (n,
    CFDI_ENC_REALS) float64.

    Examples
    --------
    FDI_FAULT of the shipped monitor DBC, its sample signal given the SAMPLE role:

    >>> import cantools
    >>> from canfdi.bus.codec import compile_layout
    >>> from canfdi.bus.e2e import make_profile
    >>> from canfdi.dbc import DBC_DIR
    >>> db = cantools.database.load_file(str(DBC_DIR / "canfdi_monitor.dbc"))
    >>> layout = compile_layout(db.get_message_by_name("FDI_FAULT"))
    >>> t = message_tables(layout, (0x80, False), make_profile("none", 0x80, False, 8, {}, "x"),
    ...                    {"Sample": "SAMPLE"})
    >>> t.length, t.sig_int.shape, int(t.sig_int[-1, ENCODE_H["CFDI_ENC_ROLE"]])
    (8, (7, 4), 5)
    """

    frame_id: int
    extended: bool
    length: int
    e2e_spec: np.ndarray
    e2e_bytes: np.ndarray
    sig_int: np.ndarray
    sig_real: np.ndarray


def message_tables(layout: MessageLayout, key: tuple[int, bool], profile: E2EProfile,
                   roles: dict[str, str]) -> MessageTables:
    """The tables cfdi_encode writes the message ``layout`` from: each signal's place, type,
    scaling and ranges as canfdi.bus.codec encodes it, and its role (``roles``: signal name ->
    an encode.h role without its prefix, "KIND", "STATE"...; a signal not named is raw 0).

    Raises
    ------
    ValueError
        For what cfdi_encode does not write: a multiplexed message, a 16-bit float, a role
        that is none of encode.h's.
    """
    sig_int, sig_real = [], []
    for sig in layout.signals:
        if sig.is_multiplexer or sig.multiplexer_ids:
            raise ValueError(f"{layout.name}.{sig.name}: the C core encodes no multiplexed "
                             "signal")
        if sig.is_float and sig.length == 16:
            raise ValueError(f"{layout.name}.{sig.name}: the C core encodes 32- and 64-bit "
                             "floats")
        role = roles.get(sig.name, "NONE")
        code = ENCODE_H.get(f"CFDI_ROLE_{role}")
        if code is None or role == "N_ROLES":
            raise ValueError(f"{layout.name}.{sig.name}: no role {role!r}")
        flags = ((_H["CFDI_SIGF_BIG"] if sig.is_big_endian else 0)
                 | (_H["CFDI_SIGF_SIGNED"] if sig.signed and not sig.is_float else 0)
                 | (_H["CFDI_SIGF_FLOAT"] if sig.is_float else 0))
        sig_int.append([sig.start, sig.length, flags, code])
        lo, hi = sig.physical_limits()
        raw_lo, raw_hi = sig.raw_limits()
        if not sig.is_float:
            raw_lo, raw_hi = _float_at_least(int(raw_lo)), _float_at_most(int(raw_hi))
        sig_real.append([sig.scale, sig.offset, lo, hi, float(raw_lo), float(raw_hi)])
    spec, table = profile.c_spec()
    return MessageTables(
        frame_id=int(key[0]), extended=bool(key[1]), length=int(layout.dlc), e2e_spec=spec,
        e2e_bytes=table,
        sig_int=np.array(sig_int, dtype=np.int64).reshape(-1, ENCODE_H["CFDI_ENC_INTS"]),
        sig_real=np.array(sig_real, dtype=np.float64).reshape(-1, ENCODE_H["CFDI_ENC_REALS"]))
