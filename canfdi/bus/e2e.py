"""End-to-end (E2E) protection of CAN payloads: one profile per message, chosen by name.

A receiver checks each frame of a protected message and reads its alive counter; a sender (the
emulator, the monitor's own frames) writes both. How is the message's *profile*:

=================  =======================================================================
name               protection
=================  =======================================================================
``none``           none: every frame passes, no counter
``counter``        an alive counter in a named signal, no CRC
``canfdi``         canfdi's own CRC-8 SAE J1850 + 8-bit counter header (``dbc/README.md``)
``autosar_p01``    AUTOSAR E2E Profile 1: CRC-8 SAE J1850 over the Data ID and the data,
                   4-bit counter 0..14
``autosar_p02``    AUTOSAR E2E Profile 2: CRC-8H2F over the data and DataIDList[counter],
                   4-bit counter 0..15
=================  =======================================================================

Every profile satisfies `E2EProfile`: ``check`` and ``counter`` for one payload,
``check_batch``, ``counters`` and ``protect_batch`` for a block of them, the two forms equal.
`make_profile` builds one from what the user wrote in the config for one message (a name, or a
mapping ``{profile: <name>, <option>: <value>, ...}``); `PROFILES` maps each name to its
factory and is the only place that branches on a profile's name. A new profile is one class
with a ``from_config`` classmethod and one line in `PROFILES`.

canfdi's own header
-------------------
Every message of canfdi's own bus (the plant DBCs and canfdi_monitor.dbc, ``dbc/README.md``;
not the vendor-style profile DBCs) carries the same two-byte header:

* byte 0: ``CRC``, the CRC-8 SAE J1850 (polynomial 0x1D, initial value 0xFF, final XOR 0xFF)
  over the **Data ID** (the 11-bit arbitration ID as two bytes, low byte first) followed by
  payload bytes ``1 .. len - 1`` (the counter and the signals);
* byte 1: ``Counter``, an 8-bit alive counter that grows by 1 (mod 256) per transmission. The
  drive's messages use the sample index ``k mod 256``, the same in every message of a period.

Folding the Data ID into the CRC without sending it (as in AUTOSAR E2E profiles) makes a frame
that is replayed or mis-routed under another arbitration ID fail the check; the counter exposes
lost, repeated and stale frames.

Limits of an 8-bit CRC over an 11-bit Data ID: there are 2048 IDs and 256 CRC values, so some
IDs must be confusable. Because the CRC is linear, a frame sent under ID ``a`` passes the check
under ID ``b`` (same length, any payload) exactly when ``a ^ b`` is one of the seven patterns in
`UNDETECTED_ID_XORS` (0x183, 0x21B, 0x398, 0x436, 0x5B5, 0x62D, 0x7AE). IDs that differ only in
their low byte are always told apart. `confusable_ids` lists the pairs of a bus's ID plan;
receivers should also check each frame's DLC against its message, and the counter.

The scalar functions (`protect`, `check`, `counter_of`, ...) work on one payload of any ID;
`crc8_batch`, `protect_batch` and `e2e_check_batch` protect and check many frames at once, and
`CanfdiProfile` is the same scheme bound to one message.

AUTOSAR profiles
----------------
Definitions as in AUTOSAR Classic Platform R4.3.0, *Specification of SW-C End-to-End
Communication Protection Library* (SWS E2ELibrary), sections 7.3 (Profile 1) and 7.4 (Profile
2); the protocol is unchanged in the later *E2E Protocol Specification* (PRS E2EProtocol, from
R19-11). Option names are AUTOSAR's configuration names in snake case.

Profile 1 (`AutosarP01`; E2E_P01ConfigType):

* CRC-8 SAE J1850 polynomial 0x1D with start value and final XOR 0x00 (SWS_E2E_00070,
  SWS_E2E_00083), i.e. the J1850 CRC's register without its 0xFF init and final XOR;
* over the Data ID first, then every byte of the ``data_length / 8`` data bytes except the CRC
  byte, in order (SWS_E2E_00082). The Data ID enters per ``data_id_mode`` (SWS_E2E_00163):
  ``both`` low byte then high byte; ``alt`` the low byte for even counters and the high byte for
  odd ones; ``low`` the low byte only (the high byte must be 0, SWS_E2E_00169); ``nibble`` the
  low byte then a 0x00 byte, the low nibble of the high byte sent in the data at
  ``data_id_nibble_offset`` and compared by the receiver (the high nibble must be 0,
  SWS_E2E_00306);
* the CRC byte at bit ``crc_offset`` (a multiple of 8), the 4-bit counter at bit
  ``counter_offset`` (a multiple of 4; low nibble of its byte when a multiple of 8, else high
  nibble), counting 0..14; the value 15 is invalid and fails the check (SWS_E2E_00020,
  SWS_E2E_00075). ``data_length`` at most 240 bits, a multiple of 8 (SWS_E2E_00018).
* Defaults: those of the E2E variants 1A/1C (SWS_E2E_00227, SWS_E2E_00307): ``crc_offset`` 0,
  ``counter_offset`` 8, ``data_id_mode`` both, ``data_id_nibble_offset`` 12; ``data_length``
  the DBC message's length. ``data_id`` (0..0xFFFF) has no default.

Profile 2 (`AutosarP02`; E2E_P02ConfigType):

* CRC-8H2F (polynomial 0x2F, start value and final XOR 0xFF; SWS_E2E_00117, SWS_E2E_00118) over
  data bytes ``1 .. data_length/8 - 1``, then the one-byte Data ID ``data_id_list[counter]``
  (SWS_E2E_00119, SWS_E2E_00120, SWS_E2E_00132, SWS_E2E_00140);
* the CRC is byte 0, the counter the low nibble of byte 1 (SWS_E2E_00122, SWS_E2E_00123; not
  configurable, SWS_E2E_00152), counting 0..15 (SWS_E2E_00128);
* options: ``data_id_list`` (16 bytes, required), ``data_length`` (default: the message's).

The receivers' state machines of both profiles (MaxDeltaCounterInit, SyncCounterInit, ...) are
not here: a profile checks one frame and reads its counter; canfdi judges counter steps itself
(`counter_delta` and the assembler).

Sources: the AUTOSAR documents themselves were not at hand; the requirement texts cited above
are as quoted in the ``@req`` comments of ArcCore's Arctic Core ``E2E_P01.c`` and
``E2E_P02.c`` (written against R4.3.0). The tests check these profiles against an independent
implementation, the ``autosar-e2e`` package on PyPI (Artur Drogunow, MIT licence; C code,
github.com/zariiii9003/autosar-e2e), frame for frame on random data, and against the worked
examples of its own test suite; the CRCs against their published check values
(``crc8(b"123456789") == 0x4B``, ``crc8h2f(b"123456789") == 0xDF``, AUTOSAR SWS CRC Library).

Batch forms
-----------
Every batch form loops over byte columns (a few, at most the payload length) and never over
frames: a block of frames costs one vectorised table look-up per byte position.

References
----------
SAE J1850, *Class B Data Communications Network Interface*, CRC-8 (check value 0x4B).
AUTOSAR CP R4.3.0, *Specification of SW-C End-to-End Communication Protection Library*
(Profiles 1 and 2); *Specification of CRC Routines* (CRC8, CRC8H2F).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canfdi.core._check import check_shape
from canfdi.core.settings import ConfigError, Option, parse_options, unknown_name

__all__ = [
    "CRC8H2F_INIT",
    "CRC8H2F_POLY",
    "CRC8H2F_XOROUT",
    "CRC8_INIT",
    "CRC8_POLY",
    "CRC8_XOROUT",
    "MAX_ARBITRATION_ID",
    "PROFILES",
    "UNDETECTED_ID_XORS",
    "AliveCounter",
    "AutosarP01",
    "AutosarP02",
    "CanfdiProfile",
    "E2EProfile",
    "NoProtection",
    "ProfileFactory",
    "SignalPlace",
    "check",
    "confusable_ids",
    "counter_delta",
    "counter_of",
    "crc8",
    "crc8_batch",
    "crc8h2f",
    "data_id",
    "e2e_check_batch",
    "e2e_crc",
    "make_profile",
    "protect",
    "protect_batch",
]

CRC8_POLY = 0x1D
CRC8_INIT = 0xFF
CRC8_XOROUT = 0xFF
# AUTOSAR's CRC8H2F (SWS CRC Library): check value 0xDF.
CRC8H2F_POLY = 0x2F
CRC8H2F_INIT = 0xFF
CRC8H2F_XOROUT = 0xFF
MAX_ARBITRATION_ID = 0x7FF
# Classic CAN: a payload longer than 8 bytes is a CAN FD frame, which our DBCs do not use.
_MAX_DLC = 8
# The smallest protected payload: CRC and counter, no signals.
_HEADER = 2
# CAN FD's longest payload.
_MAX_PAYLOAD = 64


def _make_table(poly: int) -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


_TABLE = _make_table(CRC8_POLY)
_TABLE_H2F = _make_table(CRC8H2F_POLY)
# The same tables as arrays so that a whole column of frames is one fancy-indexing look-up.
_TABLE_NP: NDArray[np.uint8] = np.array(_TABLE, dtype=np.uint8)
_TABLE_H2F_NP: NDArray[np.uint8] = np.array(_TABLE_H2F, dtype=np.uint8)
_ALL_IDS = np.arange(2048, dtype=np.int64)
# CRC register (before the final XOR) after the Data ID bytes (low, high) of every 11-bit ID.
_ID_SEEDS: NDArray[np.uint8] = _TABLE_NP[
    _TABLE_NP[CRC8_INIT ^ (_ALL_IDS & 0xFF)].astype(np.int64) ^ (_ALL_IDS >> 8)
]


def _register(table: tuple[int, ...], register: int, data: bytes | bytearray) -> int:
    """A CRC-8 register (MSB first, no reflection) after ``data``, from ``register``."""
    for byte in data:
        register = table[register ^ byte]
    return register


def _run_columns(table: NDArray[np.uint8], register: NDArray[np.uint8] | int,
                 payloads: NDArray[np.uint8], columns: Sequence[int]) -> NDArray[np.uint8]:
    """(N,) registers after the byte ``columns`` of every row of (N, L) ``payloads``."""
    reg = np.broadcast_to(np.asarray(register, dtype=np.uint8), payloads.shape[:1])
    for j in columns:
        reg = table[reg ^ payloads[:, j]]
    return np.array(reg, dtype=np.uint8)


def _run_to_length(table: NDArray[np.uint8], register: NDArray[np.uint8],
                   payloads: NDArray[np.uint8], lengths: NDArray[np.int64],
                   first: int) -> NDArray[np.uint8]:
    """(N,) registers after bytes ``first .. lengths[i] - 1`` of each row, from ``register``.

    One table look-up per byte column. A block of frames of one length (the common case: one
    message, or one DLC) runs its columns directly; frames of several lengths run one group per
    length, so no step needs a per-frame mask. Rows with ``lengths[i] <= first`` keep their
    start register. ``lengths`` must lie in 0..L.
    """
    if not len(register):
        return register
    low, high = int(lengths.min()), int(lengths.max())
    if low == high:
        return _run_bytes(table, register, payloads[:, first:high])
    reg = register.copy()
    for length in np.flatnonzero(np.bincount(lengths)):
        if length <= first:
            continue
        rows = np.flatnonzero(lengths == length)
        reg[rows] = _run_bytes(table, reg[rows], payloads[rows, first:length])
    return reg


def _run_bytes(table: NDArray[np.uint8], register: NDArray[np.uint8],
               block: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """(N,) registers after every byte column of (N, L) ``block``, in order. The columns are
    made contiguous first and looked up with take: strided columns and fancy indexing cost
    about twice as much."""
    columns = np.ascontiguousarray(block.T)
    reg = register
    for column in columns:
        reg = table.take(reg ^ column)
    return reg


def crc8(data: bytes | bytearray, init: int = CRC8_INIT) -> int:
    """CRC-8 SAE J1850 of a byte string (poly 0x1D, final XOR 0xFF).

    Parameters
    ----------
    data : bytes of any length.
    init : initial register value, 0..255 (0xFF for SAE J1850).

    Returns
    -------
    int in 0..255; ``crc8(b"123456789") == 0x4B``.
    """
    if not 0 <= init <= 0xFF:
        raise ValueError(f"init must be in 0..255, got {init}")
    return _register(_TABLE, init, data) ^ CRC8_XOROUT


def crc8h2f(data: bytes | bytearray, init: int = CRC8H2F_INIT) -> int:
    """AUTOSAR's CRC-8H2F of a byte string (poly 0x2F, final XOR 0xFF), used by E2E Profile 2.

    Parameters
    ----------
    data : bytes of any length.
    init : initial register value, 0..255 (0xFF for CRC8H2F).

    Returns
    -------
    int in 0..255; ``crc8h2f(b"123456789") == 0xDF``.
    """
    if not 0 <= init <= 0xFF:
        raise ValueError(f"init must be in 0..255, got {init}")
    return _register(_TABLE_H2F, init, data) ^ CRC8H2F_XOROUT


def _check_id(arbitration_id: int) -> None:
    if not 0 <= arbitration_id <= MAX_ARBITRATION_ID:
        raise ValueError(
            f"arbitration_id must be an 11-bit ID in 0..0x7FF, got {arbitration_id:#x}"
        )


def data_id(arbitration_id: int) -> bytes:
    """The Data ID bytes that precede the payload in the CRC.

    Parameters
    ----------
    arbitration_id : 11-bit CAN identifier, 0..0x7FF.

    Returns
    -------
    (2,) bytes: low byte, high byte.
    """
    _check_id(arbitration_id)
    return bytes((arbitration_id & 0xFF, arbitration_id >> 8))


def _undetected_id_xors() -> tuple[int, ...]:
    # The CRC register is linear in the message, so two messages that differ only in the Data
    # ID collide iff the CRC register of the difference (init 0, no final XOR) is 0, whatever
    # the payload and its length (trailing bytes multiply by x^8, coprime to the polynomial).
    return tuple(
        d for d in range(1, MAX_ARBITRATION_ID + 1) if crc8(data_id(d), init=0) == CRC8_XOROUT
    )


# 7 of the 2047 possible ID differences a ^ b that the CRC cannot see.
UNDETECTED_ID_XORS: tuple[int, ...] = _undetected_id_xors()


def confusable_ids(ids: list[int] | tuple[int, ...]) -> list[tuple[int, int]]:
    """Pairs of IDs whose frames of equal length pass each other's CRC check.

    Parameters
    ----------
    ids : (M,) 11-bit arbitration IDs, e.g. every message of a DBC file.

    Returns
    -------
    list of (a, b) with a < b and ``a ^ b`` in `UNDETECTED_ID_XORS`, sorted.
    """
    unique = sorted(set(ids))
    for arbitration_id in unique:
        _check_id(arbitration_id)
    xors = set(UNDETECTED_ID_XORS)
    return [(a, b) for i, a in enumerate(unique) for b in unique[i + 1 :] if a ^ b in xors]


def _check_payload(payload: bytes | bytearray) -> None:
    if not _HEADER <= len(payload) <= _MAX_DLC:
        raise ValueError(
            f"payload must hold 2..8 bytes (CRC, counter, signals), got {len(payload)}"
        )


def e2e_crc(arbitration_id: int, payload: bytes | bytearray) -> int:
    """The CRC byte a protected payload must carry.

    Parameters
    ----------
    arbitration_id : 11-bit CAN identifier, 0..0x7FF.
    payload : (dlc,) bytes with 2 <= dlc <= 8; byte 0 (the CRC itself) is ignored.

    Returns
    -------
    int in 0..255: CRC-8 SAE J1850 over Data ID + ``payload[1:]``.
    """
    _check_payload(payload)
    return crc8(data_id(arbitration_id) + bytes(payload[1:]))


def protect(arbitration_id: int, payload: bytes | bytearray, counter: int) -> bytes:
    """Write the alive counter into byte 1 and the CRC into byte 0.

    Parameters
    ----------
    arbitration_id : 11-bit CAN identifier, 0..0x7FF.
    payload : (dlc,) bytes with 2 <= dlc <= 8 (e.g. from ``cantools`` ``Message.encode``);
        bytes 0 and 1 are overwritten in the returned copy, the argument is not modified.
    counter : non-negative int, reduced mod 256 so that a sample index k can be passed as is.

    Returns
    -------
    (dlc,) bytes that pass `check`.
    """
    _check_payload(payload)
    if counter < 0:
        raise ValueError(f"counter must be >= 0, got {counter}")
    frame = bytearray(payload)
    frame[1] = counter & 0xFF
    frame[0] = e2e_crc(arbitration_id, frame)
    return bytes(frame)


def check(arbitration_id: int, payload: bytes | bytearray) -> bool:
    """Whether a received payload carries the right CRC for its arbitration ID.

    Parameters
    ----------
    arbitration_id : 11-bit CAN identifier, 0..0x7FF.
    payload : (dlc,) received bytes.

    Returns
    -------
    True when byte 0 equals `e2e_crc`; False for a wrong CRC and for payloads shorter than 2 or
    longer than 8 bytes (they cannot be one of our protected frames, and a monitor must count
    them as invalid rather than crash on them).
    """
    _check_id(arbitration_id)
    if not _HEADER <= len(payload) <= _MAX_DLC:
        return False
    return payload[0] == e2e_crc(arbitration_id, payload)


def counter_of(payload: bytes | bytearray) -> int:
    """The alive counter (byte 1) of a protected payload.

    Parameters
    ----------
    payload : (dlc,) bytes with dlc >= 2.

    Returns
    -------
    int in 0..255.
    """
    if len(payload) < _HEADER:
        raise ValueError(f"payload must hold at least 2 bytes, got {len(payload)}")
    return payload[1]


def counter_delta(previous: int, current: int) -> int:
    """Counter steps between two receptions of one message, modulo 256.

    Parameters
    ----------
    previous, current : counters in 0..255.

    Returns
    -------
    int in 0..255: 1 for the next frame, 0 for a repeated frame, d > 1 when d - 1 frames were
    lost (or, since the counter wraps, 256 * m + d - 1 of them).
    """
    for name, value in (("previous", previous), ("current", current)):
        if not 0 <= value <= 0xFF:
            raise ValueError(f"{name} must be in 0..255, got {value}")
    return (current - previous) & 0xFF


def _byte_array(name: str, value: ArrayLike) -> NDArray[np.uint8]:
    array = np.asarray(value)
    if array.dtype == np.uint8:
        return array
    if array.size and (
        not np.issubdtype(array.dtype, np.integer) or array.min() < 0 or array.max() > 0xFF
    ):
        raise ValueError(f"{name} must hold bytes (integers in 0..255)")
    return array.astype(np.uint8)


def crc8_batch(
    data: ArrayLike, init: int = CRC8_INIT, lengths: ArrayLike | None = None
) -> NDArray[np.uint8]:
    """CRC-8 SAE J1850 of many byte strings at once.

    Parameters
    ----------
    data : (N, L) uint8, one byte string per row.
    init : initial register value, 0..255.
    lengths : (N,) ints in 0..L, optional; row i's CRC covers ``data[i, :lengths[i]]`` only
        (bytes beyond are ignored). Default: every row has L bytes.

    Returns
    -------
    (N,) uint8; row i equals ``crc8(bytes(data[i, :lengths[i]]), init)``.
    """
    data = check_shape("data", _byte_array("data", data), ("N", "L"))
    if not 0 <= init <= 0xFF:
        raise ValueError(f"init must be in 0..255, got {init}")
    n_rows, n_cols = data.shape
    if lengths is not None:
        lengths = check_shape("lengths", lengths, (n_rows,))
        if lengths.size and (lengths.min() < 0 or lengths.max() > n_cols):
            raise ValueError(f"lengths must be in 0..{n_cols}")
    crc = np.full(n_rows, init, dtype=np.uint8)
    # Columns are few (Data ID + at most 7 payload bytes), frames are many: iterate the short axis.
    for j in range(n_cols):
        updated = _TABLE_NP[crc ^ data[:, j]]
        crc = updated if lengths is None else np.where(j < lengths, updated, crc)
    return crc ^ np.uint8(CRC8_XOROUT)


def e2e_check_batch(ids: ArrayLike, payloads: ArrayLike, dlc: ArrayLike) -> NDArray[np.bool_]:
    """`check` for many frames at once.

    Parameters
    ----------
    ids : (N,) 11-bit arbitration IDs, 0..0x7FF.
    payloads : (N, 8) uint8 frame data, zero- or garbage-padded beyond each frame's DLC.
    dlc : (N,) data length codes, 0..8; only the first ``dlc[i]`` bytes of row i count.

    Returns
    -------
    (N,) bool: CRC ok. Frames with dlc < 2 (no room for CRC and counter) are False.
    """
    payloads = check_shape("payloads", _byte_array("payloads", payloads), ("N", _MAX_DLC))
    n_frames = payloads.shape[0]
    ids = check_shape("ids", ids, (n_frames,))
    dlc = check_shape("dlc", dlc, (n_frames,))
    if ids.size and (ids.min() < 0 or ids.max() > MAX_ARBITRATION_ID):
        raise ValueError("ids must be 11-bit arbitration IDs in 0..0x7FF")
    if dlc.size and (dlc.min() < 0 or dlc.max() > _MAX_DLC):
        raise ValueError("dlc must be in 0..8")
    # The register after the two Data ID bytes depends on the ID only: start every frame from
    # that seed (one look-up), then run its payload bytes 1..dlc-1.
    dlc = dlc.astype(np.int64)
    crc = _run_to_length(_TABLE_NP, _ID_SEEDS[ids.astype(np.int64)], payloads, dlc, 1)
    return ((crc ^ np.uint8(CRC8_XOROUT)) == payloads[:, 0]) & (dlc >= _HEADER)


def _counter_values(counters: ArrayLike, n_frames: int) -> NDArray[np.int64]:
    """(N,) int64 counters from a scalar or (N,) non-negative integers."""
    counters = np.asarray(counters)
    if counters.ndim > 1 or (counters.ndim == 1 and counters.shape != (n_frames,)):
        raise ValueError(f"counters must be a scalar or have shape ({n_frames},), got "
                         f"{counters.shape}")
    if counters.size and not np.issubdtype(counters.dtype, np.integer):
        raise ValueError(f"counters must be integers, got dtype {counters.dtype}")
    if counters.size and counters.min() < 0:
        raise ValueError("counters must be >= 0")
    return np.broadcast_to(counters, (n_frames,)).astype(np.int64)


def protect_batch(
    arbitration_id: int | ArrayLike, payloads: ArrayLike, counters: int | ArrayLike
) -> NDArray[np.uint8]:
    """`protect` for many frames of one length at once (a block of samples of one message).

    Parameters
    ----------
    arbitration_id : 11-bit ID, one for all frames or (N,) one per frame.
    payloads : (N, dlc) uint8 with 2 <= dlc <= 8; bytes 0 and 1 are overwritten in the copy.
    counters : non-negative int or (N,) ints, reduced mod 256 (sample indices may be passed).

    Returns
    -------
    (N, dlc) uint8, a new array; row i equals ``protect(id_i, payloads[i], counters[i])``.
    """
    frames = _byte_array("payloads", payloads).copy()
    if frames.ndim != 2 or not _HEADER <= frames.shape[1] <= _MAX_DLC:
        raise ValueError(
            f"payloads must have shape (N, dlc) with 2 <= dlc <= 8, got {frames.shape}"
        )
    n_frames = frames.shape[0]
    ids = np.broadcast_to(np.asarray(arbitration_id), (n_frames,)).astype(np.int64)
    if ids.size and (ids.min() < 0 or ids.max() > MAX_ARBITRATION_ID):
        raise ValueError("arbitration_id must be 11-bit IDs in 0..0x7FF")
    frames[:, 1] = _counter_values(counters, n_frames) & 0xFF
    seeds = _ID_SEEDS[ids]
    crc = _run_columns(_TABLE_NP, seeds, frames, range(1, frames.shape[1]))
    frames[:, 0] = crc ^ np.uint8(CRC8_XOROUT)
    return frames


# --------------------------------------------------------------------------------------------
# Profiles
# --------------------------------------------------------------------------------------------

SignalPlace = tuple[int, int, str]
"""Where a signal sits, in cantools' conventions: ``(signal.start, signal.length,
signal.byte_order)`` with DBC start-bit numbering and 'little_endian' or 'big_endian'."""


@runtime_checkable
class E2EProfile(Protocol):
    """What every E2E profile offers: a check and a counter, per frame and per block.

    Attributes
    ----------
    name : the profile's registry name (a key of `PROFILES`).
    counter_modulus : the alive counter's modulus (None: the profile has no counter).

    The streaming forms (``check``, ``counter``) and the batch forms (``check_batch``,
    ``counters``) give the same answers frame for frame. A profile is stateless: judging counter
    steps across frames is the receiver's business.

    Examples
    --------
    >>> profile = make_profile("canfdi", 0x104, False, 8, {}, "bus.e2e.messages.DRIVE_CMD")
    >>> isinstance(profile, E2EProfile)
    True
    >>> frames = profile.protect_batch(np.zeros((3, 8), np.uint8), np.array([255, 256, 257]))
    >>> profile.check_batch(frames, np.array([8, 8, 7])).tolist(), profile.counters(frames)
    ([True, True, False], array([255,   0,   1]))
    """

    name: str
    counter_modulus: int | None

    def check(self, payload: bytes) -> bool:
        """Whether one received payload passes (streaming form of `check_batch`).

        Parameters
        ----------
        payload : (len,) the frame's bytes as received, of any length.

        Returns
        -------
        bool; False (never an exception) for a payload too short or too long for the profile.
        """
        ...

    def check_batch(self, payloads: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        """Whether each of a block of received payloads passes.

        Parameters
        ----------
        payloads : (N, L) uint8, one frame per row, zero- or garbage-padded beyond its length.
        lengths : (N,) ints in 0..L, each frame's actual length; bytes beyond it do not count.

        Returns
        -------
        (N,) bool, row i equal to ``check(bytes(payloads[i, :lengths[i]]))``.
        """
        ...

    def counters(self, payloads: np.ndarray) -> np.ndarray | None:
        """The alive counter of each of a block of payloads.

        Parameters
        ----------
        payloads : (N, L) uint8; a row too short to hold the counter reads as zero-padded.

        Returns
        -------
        (N,) int64, or None for a profile without a counter. Meaningful where the check passes.
        """
        ...

    def counter(self, payload: bytes) -> int | None:
        """The alive counter of one payload (streaming form of `counters`), or None."""
        ...

    def protect_batch(self, payloads: np.ndarray, counters: np.ndarray) -> np.ndarray:
        """Sender side: write the counter and the CRC into a block of payloads of one message.

        Parameters
        ----------
        payloads : (N, L) uint8 (L at least what the profile covers); the argument is not
            modified.
        counters : (N,) non-negative ints (or one for all), reduced modulo `counter_modulus`
            (sample indices may be passed as they are).

        Returns
        -------
        (N, L) uint8, a new array whose rows pass `check_batch`.
        """
        ...


ProfileFactory = Callable[[Mapping[str, Any], int, bool, int, Mapping[str, SignalPlace], str],
                          E2EProfile]
"""``factory(options, frame_id, is_extended, length, signals, where)`` -> a profile; options
are the user's spec for the message less its ``profile`` key."""


@dataclass(frozen=True)
class _BitField:
    """An unsigned field of a payload, as (byte, lowest bit, width, value shift) pieces."""

    length: int
    pieces: tuple[tuple[int, int, int, int], ...]

    @classmethod
    def of(cls, start: int, length: int, byte_order: str) -> _BitField:
        """The field of a signal at DBC start bit ``start`` (cantools' ``Signal.start``)."""
        pieces = []
        done = 0
        if byte_order == "little_endian":
            # start is the LSB; bit b of byte k is bit 8k + b, counted upward.
            position = start
            while done < length:
                byte, bit = divmod(position, 8)
                width = min(8 - bit, length - done)
                pieces.append((byte, bit, width, done))
                position += width
                done += width
        elif byte_order == "big_endian":
            # start is the MSB in the sawtooth numbering; walk MSB-first through the bytes.
            linear = 8 * (start // 8) + 7 - start % 8
            while done < length:
                byte, from_top = divmod(linear, 8)
                width = min(8 - from_top, length - done)
                pieces.append((byte, 8 - from_top - width, width, length - done - width))
                linear += width
                done += width
        else:
            raise ValueError(f"byte_order must be little_endian or big_endian, got {byte_order!r}")
        return cls(length, tuple(pieces))

    @property
    def n_bytes(self) -> int:
        """The shortest payload that holds the field."""
        return max(byte for byte, *_ in self.pieces) + 1

    def read(self, payload: bytes | bytearray) -> int:
        value = 0
        for byte, bit, width, shift in self.pieces:
            value |= ((payload[byte] >> bit) & ((1 << width) - 1)) << shift
        return value

    def read_batch(self, payloads: NDArray[np.uint8]) -> NDArray[np.int64]:
        value = np.zeros(payloads.shape[0], dtype=np.int64)
        for byte, bit, width, shift in self.pieces:
            value |= ((payloads[:, byte] >> bit) & ((1 << width) - 1)).astype(np.int64) << shift
        return value

    def write_batch(self, frames: NDArray[np.uint8], values: NDArray[np.int64]) -> None:
        for byte, bit, width, shift in self.pieces:
            mask = ((1 << width) - 1) << bit
            field = ((values >> shift) << bit) & mask
            frames[:, byte] = (frames[:, byte] & (0xFF ^ mask)) | field.astype(np.uint8)


def _frames(payloads: ArrayLike, lengths: ArrayLike) -> tuple[NDArray[np.uint8], NDArray[np.int64]]:
    """Validated (N, L) uint8 payloads and (N,) int64 lengths in 0..L."""
    payloads = check_shape("payloads", _byte_array("payloads", payloads), ("N", "L"))
    lengths = check_shape("lengths", lengths, (payloads.shape[0],))
    if lengths.size and not np.issubdtype(lengths.dtype, np.integer):
        raise ValueError(f"lengths must be integers, got dtype {lengths.dtype}")
    if lengths.size and (lengths.min() < 0 or lengths.max() > payloads.shape[1]):
        raise ValueError(f"lengths must be in 0..{payloads.shape[1]} (the payloads' width)")
    return payloads, lengths.astype(np.int64)


def _padded(payloads: ArrayLike, width: int) -> NDArray[np.uint8]:
    """(N, >= width) uint8: the payloads, zero-padded on the right when narrower."""
    payloads = check_shape("payloads", _byte_array("payloads", payloads), ("N", "L"))
    if payloads.shape[1] >= width:
        return payloads
    wider = np.zeros((payloads.shape[0], width), dtype=np.uint8)
    wider[:, : payloads.shape[1]] = payloads
    return wider


def _padded_bytes(payload: bytes | bytearray, width: int) -> bytes:
    return bytes(payload).ljust(width, b"\x00")


def _protectable(payloads: ArrayLike, width: int, what: str) -> NDArray[np.uint8]:
    """A copy of (N, L) payloads with L >= width, for a sender to write into."""
    frames = _byte_array("payloads", payloads)
    if frames.ndim != 2 or frames.shape[1] < width:
        raise ValueError(f"payloads must have shape (N, L) with L >= {width} ({what}), got "
                         f"{frames.shape}")
    return frames.copy()


@contextmanager
def _options_of(where: str) -> Iterator[None]:
    """Re-raise a constructor's ConfigError (named by option) under the spec's dotted path."""
    try:
        yield
    except ConfigError as error:
        message = str(error).removeprefix(f"{error.field}: ")
        raise ConfigError(f"{where}.{error.field}", message) from None


def _no_options(options: Mapping[str, Any], name: str, where: str) -> None:
    """A ConfigError naming the first option given to a profile that takes none."""
    if options:
        key = next(iter(options))
        raise ConfigError(f"{where}.{key}", f"unknown key (profile {name} takes no options)")


class _Profile:
    """What all profiles share: the one-payload protect."""

    name: str
    counter_modulus: int | None = None

    def protect_batch(self, payloads: np.ndarray, counters: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def protect(self, payload: bytes | bytearray, counter: int) -> bytes:
        """Sender side for one payload: `protect_batch` of one row, as bytes."""
        row = np.frombuffer(bytes(payload), dtype=np.uint8)[None, :]
        return self.protect_batch(row, np.array([counter], dtype=np.int64))[0].tobytes()


class NoProtection(_Profile):
    """The ``none`` profile: no CRC, no counter; every frame passes.

    Examples
    --------
    >>> profile = make_profile("none", 0x123, False, 8, {}, "bus.e2e.messages.Speed")
    >>> profile.check(b""), profile.counter(b"\\x01\\x02"), profile.counter_modulus
    (True, None, None)
    """

    name: str = "none"
    counter_modulus = None

    @classmethod
    def from_config(cls, options: Mapping[str, Any], frame_id: int, is_extended: bool,
                    length: int, signals: Mapping[str, SignalPlace], where: str) -> NoProtection:
        """The profile from its config options (none allowed)."""
        _no_options(options, cls.name, where)
        return cls()

    def check(self, payload: bytes) -> bool:
        return True

    def check_batch(self, payloads: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        payloads, lengths = _frames(payloads, lengths)
        return np.ones(payloads.shape[0], dtype=np.bool_)

    def counters(self, payloads: np.ndarray) -> None:
        return None

    def counter(self, payload: bytes) -> None:
        return None

    def protect_batch(self, payloads: np.ndarray, counters: np.ndarray) -> np.ndarray:
        frames = _protectable(payloads, 0, "any payload")
        _counter_values(counters, frames.shape[0])
        return frames

    def __repr__(self) -> str:
        return "NoProtection()"


# Counters are read into int64; AUTOSAR's longest alive counter (Profile 7) has 32 bits.
_MAX_COUNTER_BITS = 32


class AliveCounter(_Profile):
    """The ``counter`` profile: an unsigned alive counter in one signal, no CRC.

    Parameters
    ----------
    signal : the counter signal's name (for messages).
    start, length, byte_order : where it sits, in cantools' conventions (DBC start bit,
        1..32 bits, 'little_endian' or 'big_endian').
    modulus : the counter counts 0 .. modulus - 1, in 2 .. 2**length (default 2**length).

    A frame passes when it is long enough to hold the signal and its counter is below the
    modulus (a 4-bit counter of modulus 15 never sends 15).

    Examples
    --------
    >>> signals = {"Alive": (8, 4, "little_endian")}
    >>> profile = make_profile({"profile": "counter", "signal": "Alive", "modulus": 15},
    ...                        0x123, False, 2, signals, "bus.e2e.messages.Status")
    >>> frame = profile.protect(bytes(2), 31)
    >>> frame.hex(), profile.counter(frame), profile.check(frame)
    ('0001', 1, True)
    >>> profile.check(b"\\x00\\x0f")
    False
    """

    name: str = "counter"

    def __init__(self, signal: str, start: int, length: int, byte_order: str,
                 modulus: int | None = None) -> None:
        if not 1 <= length <= _MAX_COUNTER_BITS:
            raise ConfigError("signal", f"{signal} has {length} bits; an alive counter needs "
                                        f"1..{_MAX_COUNTER_BITS}")
        if start < 0:
            raise ConfigError("signal", f"{signal} starts at bit {start}, before the payload")
        if modulus is None:
            modulus = 1 << length
        if not 2 <= modulus <= 1 << length:
            raise ConfigError("modulus", f"expected an integer in [2, {1 << length}] (a "
                                         f"{length}-bit signal holds {1 << length} values), "
                                         f"got {modulus}")
        self.signal = signal
        self.start = start
        self.length = length
        self.byte_order = byte_order
        self.counter_modulus = modulus
        self._field = _BitField.of(start, length, byte_order)

    @classmethod
    def from_config(cls, options: Mapping[str, Any], frame_id: int, is_extended: bool,
                    length: int, signals: Mapping[str, SignalPlace], where: str) -> AliveCounter:
        """The profile from ``signal`` (required) and ``modulus`` (default 2**bits)."""
        given = parse_options(options, {"signal": Option(str), "modulus": Option(int, 2)}, where)
        if "signal" not in given:
            raise ConfigError(f"{where}.signal", "missing: name the counter signal of the "
                                                 f"message (signals: {', '.join(sorted(signals))})")
        signal = given["signal"]
        if signal not in signals:
            raise unknown_name(f"{where}.signal", "signal", signal, signals)
        start, bits, byte_order = signals[signal]
        with _options_of(where):
            profile = cls(signal, start, bits, byte_order, given.get("modulus"))
        if profile._field.n_bytes > length:
            raise ConfigError(f"{where}.signal", f"{signal} reaches byte {profile._field.n_bytes}"
                                                 f" of a {length}-byte message")
        return profile

    def check(self, payload: bytes) -> bool:
        if len(payload) < self._field.n_bytes:
            return False
        return self._field.read(payload) < self.counter_modulus

    def check_batch(self, payloads: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        payloads, lengths = _frames(payloads, lengths)
        values = self._field.read_batch(_padded(payloads, self._field.n_bytes))
        return (lengths >= self._field.n_bytes) & (values < self.counter_modulus)

    def counters(self, payloads: np.ndarray) -> np.ndarray:
        return self._field.read_batch(_padded(payloads, self._field.n_bytes))

    def counter(self, payload: bytes) -> int:
        return self._field.read(_padded_bytes(payload, self._field.n_bytes))

    def protect_batch(self, payloads: np.ndarray, counters: np.ndarray) -> np.ndarray:
        frames = _protectable(payloads, self._field.n_bytes, f"the signal {self.signal}")
        values = _counter_values(counters, frames.shape[0]) % self.counter_modulus
        self._field.write_batch(frames, values)
        return frames

    def __repr__(self) -> str:
        return (f"AliveCounter(signal={self.signal!r}, start={self.start}, length={self.length},"
                f" byte_order={self.byte_order!r}, modulus={self.counter_modulus})")


class CanfdiProfile(_Profile):
    """The ``canfdi`` profile: canfdi's own header (module docstring) for one 11-bit ID.

    Parameters
    ----------
    frame_id : the message's 11-bit arbitration ID (its Data ID), 0..0x7FF.

    Frames of 2..8 bytes; the CRC covers each frame's own length, like `check`.

    Examples
    --------
    >>> profile = make_profile("canfdi", 0x105, False, 8, {}, "bus.e2e.messages.DRIVE_CURRENTS")
    >>> frame = profile.protect(bytes(8), 258)
    >>> frame == protect(0x105, bytes(8), 258), profile.counter(frame), profile.check(frame)
    (True, 2, True)
    """

    name: str = "canfdi"

    def __init__(self, frame_id: int) -> None:
        _check_id(frame_id)
        self.frame_id = frame_id
        self.counter_modulus = 256
        self._seed = int(_ID_SEEDS[frame_id])

    @classmethod
    def from_config(cls, options: Mapping[str, Any], frame_id: int, is_extended: bool,
                    length: int, signals: Mapping[str, SignalPlace], where: str) -> CanfdiProfile:
        """The profile of one message (no options): an 11-bit ID, 2..8 bytes."""
        _no_options(options, cls.name, where)
        if is_extended or not 0 <= frame_id <= MAX_ARBITRATION_ID:
            raise ConfigError(where, f"profile canfdi protects 11-bit IDs only (its Data ID is "
                                     f"the 11-bit arbitration ID); this message has the 29-bit "
                                     f"ID {frame_id:#x}")
        if not _HEADER <= length <= _MAX_DLC:
            raise ConfigError(where, f"profile canfdi needs a message of 2..8 bytes (CRC, "
                                     f"counter, signals), this one has {length}")
        return cls(frame_id)

    def check(self, payload: bytes) -> bool:
        if not _HEADER <= len(payload) <= _MAX_DLC:
            return False
        return payload[0] == _register(_TABLE, self._seed, payload[1:]) ^ CRC8_XOROUT

    def check_batch(self, payloads: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        payloads, lengths = _frames(payloads, lengths)
        if payloads.shape[1] < _HEADER:
            return np.zeros(payloads.shape[0], dtype=np.bool_)
        valid = lengths >= _HEADER
        if payloads.shape[1] > _MAX_DLC:
            valid &= lengths <= _MAX_DLC
            lengths = np.minimum(lengths, _MAX_DLC)
        start = np.full(payloads.shape[0], self._seed, dtype=np.uint8)
        crc = _run_to_length(_TABLE_NP, start, payloads, lengths, 1)
        return ((crc ^ np.uint8(CRC8_XOROUT)) == payloads[:, 0]) & valid

    def counters(self, payloads: np.ndarray) -> np.ndarray:
        return _padded(payloads, _HEADER)[:, 1].astype(np.int64)

    def counter(self, payload: bytes) -> int:
        return _padded_bytes(payload, _HEADER)[1]

    def protect_batch(self, payloads: np.ndarray, counters: np.ndarray) -> np.ndarray:
        return protect_batch(self.frame_id, payloads, counters)

    def __repr__(self) -> str:
        return f"CanfdiProfile(frame_id={self.frame_id:#x})"


def _multiple(key: str, value: int, of: int) -> None:
    if value % of:
        raise ConfigError(key, f"expected a multiple of {of} (bits), got {value}")


_P01_MODES = ("both", "alt", "low", "nibble")
# Profile 1's counter skips 0xF, the value that marks an error (SWS_E2E_00020).
_P01_INVALID_COUNTER = 0xF
_P01_MAX_DATA_LENGTH = 240


class AutosarP01(_Profile):
    """The ``autosar_p01`` profile: AUTOSAR E2E Profile 1 (definitions: module docstring).

    Parameters
    ----------
    data_id : the Data ID, 0..0xFFFF (``low`` mode: 0..0xFF; ``nibble`` mode: 0..0xFFF).
    data_length : the protected data's length in bits, a multiple of 8 in 16..240.
    data_id_mode : 'both' (default), 'alt', 'low' or 'nibble': E2E_P01_DATAID_BOTH, _ALT,
        _LOW, _NIBBLE (in ARXML's DataIdModeEnum: ALL-16-BIT, ALTERNATING-8-BIT, LOWER-8-BIT,
        LOWER-12-BIT).
    crc_offset : bit offset of the CRC byte, a multiple of 8 (default 0).
    counter_offset : bit offset of the 4-bit counter, a multiple of 4 (default 8).
    data_id_nibble_offset : bit offset of the explicit Data ID nibble in ``nibble`` mode, a
        multiple of 4 (default 12).

    Frames shorter than ``data_length / 8`` bytes fail; bytes beyond it are not covered.

    Examples
    --------
    The worked example of autosar-e2e's tests (Data ID 0x123, 8 zero bytes, counter 1):

    >>> profile = make_profile({"profile": "autosar_p01", "data_id": 0x123}, 0x123, False, 8,
    ...                        {}, "bus.e2e.messages.Brake")
    >>> frame = profile.protect(bytes(8), 1)
    >>> frame.hex(), profile.counter(frame), profile.check(frame), profile.counter_modulus
    ('9101000000000000', 1, True, 15)
    """

    name: str = "autosar_p01"

    def __init__(self, data_id: int, data_length: int, data_id_mode: str = "both",
                 crc_offset: int = 0, counter_offset: int = 8,
                 data_id_nibble_offset: int = 12) -> None:
        if data_id_mode not in _P01_MODES:
            raise unknown_name("data_id_mode", "Data ID mode", data_id_mode, _P01_MODES)
        id_max = {"low": 0xFF, "nibble": 0xFFF}.get(data_id_mode, 0xFFFF)
        if not 0 <= data_id <= id_max:
            raise ConfigError("data_id", f"expected an integer in [0, {id_max:#x}] "
                                         f"(data_id_mode {data_id_mode}), got {data_id:#x}")
        _multiple("data_length", data_length, 8)
        if not 16 <= data_length <= _P01_MAX_DATA_LENGTH:
            raise ConfigError("data_length", f"expected 16..{_P01_MAX_DATA_LENGTH} bits (CRC "
                                             f"byte and counter .. 30 bytes), got {data_length}")
        _multiple("crc_offset", crc_offset, 8)
        _multiple("counter_offset", counter_offset, 4)
        if not 0 <= crc_offset <= data_length - 8:
            raise ConfigError("crc_offset", f"expected 0..{data_length - 8} (inside the "
                                            f"{data_length}-bit data), got {crc_offset}")
        if not 0 <= counter_offset <= data_length - 4:
            raise ConfigError("counter_offset", f"expected 0..{data_length - 4} (inside the "
                                                f"{data_length}-bit data), got {counter_offset}")
        if counter_offset // 8 == crc_offset // 8:
            raise ConfigError("counter_offset", f"the counter (bit {counter_offset}) is in the "
                                                f"CRC byte (bits {crc_offset}..{crc_offset + 7})")
        if data_id_mode == "nibble":
            _multiple("data_id_nibble_offset", data_id_nibble_offset, 4)
            if not 0 <= data_id_nibble_offset <= data_length - 4:
                raise ConfigError("data_id_nibble_offset",
                                  f"expected 0..{data_length - 4} (inside the {data_length}-bit "
                                  f"data), got {data_id_nibble_offset}")
            if data_id_nibble_offset // 8 == crc_offset // 8:
                raise ConfigError("data_id_nibble_offset", "the Data ID nibble is in the CRC byte")
            if data_id_nibble_offset == counter_offset:
                raise ConfigError("data_id_nibble_offset", "the Data ID nibble is the counter")
        self.data_id = data_id
        self.data_length = data_length
        self.data_id_mode = data_id_mode
        self.crc_offset = crc_offset
        self.counter_offset = counter_offset
        self.data_id_nibble_offset = data_id_nibble_offset
        self.counter_modulus = 15
        self._n_bytes = data_length // 8
        self._crc_byte = crc_offset // 8
        self._columns = tuple(j for j in range(self._n_bytes) if j != self._crc_byte)
        self._counter = _BitField.of(counter_offset, 4, "little_endian")
        self._nibble = (_BitField.of(data_id_nibble_offset, 4, "little_endian")
                        if data_id_mode == "nibble" else None)
        low, high = data_id & 0xFF, data_id >> 8
        # The register (start value 0x00) after the Data ID: [even counter, odd counter].
        seeds = {"both": (_TABLE[_TABLE[low] ^ high],) * 2,
                 "low": (_TABLE[low],) * 2,
                 "alt": (_TABLE[low], _TABLE[high]),
                 "nibble": (_TABLE[_TABLE[low]],) * 2}[data_id_mode]
        self._seeds = seeds
        self._seeds_np = np.array(seeds, dtype=np.uint8)

    _OPTIONS: ClassVar[dict[str, Option]] = {
        "data_id": Option(int, 0, 0xFFFF),
        "data_length": Option(int, 16, _P01_MAX_DATA_LENGTH),
        "data_id_mode": Option(str, choices=_P01_MODES),
        "crc_offset": Option(int, 0),
        "counter_offset": Option(int, 0),
        "data_id_nibble_offset": Option(int, 0),
    }

    @classmethod
    def from_config(cls, options: Mapping[str, Any], frame_id: int, is_extended: bool,
                    length: int, signals: Mapping[str, SignalPlace], where: str) -> AutosarP01:
        """The profile from ``data_id`` (required) and the options of `AutosarP01`."""
        given = parse_options(options, cls._OPTIONS, where)
        if "data_id" not in given:
            raise ConfigError(f"{where}.data_id", "missing: the message's AUTOSAR Data ID "
                                                  "(0..0xFFFF), which the sender folds into the "
                                                  "CRC")
        if length < _HEADER:
            raise ConfigError(where, f"profile autosar_p01 needs a message of at least 2 bytes "
                                     f"(CRC and counter), this one has {length}")
        if "data_length" not in given and 8 * length > _P01_MAX_DATA_LENGTH:
            raise ConfigError(f"{where}.data_length", f"missing: the {length}-byte message is "
                                                      f"longer than Profile 1's "
                                                      f"{_P01_MAX_DATA_LENGTH} bits; say how "
                                                      f"many of its bits are protected")
        given.setdefault("data_length", 8 * length)
        if given["data_length"] > 8 * length:
            raise ConfigError(f"{where}.data_length", f"{given['data_length']} bits do not fit "
                                                      f"the {length}-byte message")
        with _options_of(where):
            return cls(**given)

    def _crc_register(self, payloads: NDArray[np.uint8],
                      counters: NDArray[np.int64]) -> NDArray[np.uint8]:
        seed = (self._seeds_np[counters & 1] if self.data_id_mode == "alt"
                else self._seeds_np[0])
        return _run_columns(_TABLE_NP, seed, payloads, self._columns)

    def check(self, payload: bytes) -> bool:
        if len(payload) < self._n_bytes:
            return False
        counter = self._counter.read(payload)
        if counter == _P01_INVALID_COUNTER:
            return False
        if self._nibble is not None and self._nibble.read(payload) != (self.data_id >> 8) & 0xF:
            return False
        register = self._seeds[counter & 1]
        for j in self._columns:
            register = _TABLE[register ^ payload[j]]
        return payload[self._crc_byte] == register

    def check_batch(self, payloads: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        payloads, lengths = _frames(payloads, lengths)
        if payloads.shape[1] < self._n_bytes:
            return np.zeros(payloads.shape[0], dtype=np.bool_)
        counters = self._counter.read_batch(payloads)
        ok = (lengths >= self._n_bytes) & (counters != _P01_INVALID_COUNTER)
        if self._nibble is not None:
            ok &= self._nibble.read_batch(payloads) == (self.data_id >> 8) & 0xF
        return ok & (self._crc_register(payloads, counters) == payloads[:, self._crc_byte])

    def counters(self, payloads: np.ndarray) -> np.ndarray:
        return self._counter.read_batch(_padded(payloads, self._counter.n_bytes))

    def counter(self, payload: bytes) -> int:
        return self._counter.read(_padded_bytes(payload, self._counter.n_bytes))

    def protect_batch(self, payloads: np.ndarray, counters: np.ndarray) -> np.ndarray:
        frames = _protectable(payloads, self._n_bytes, f"data_length {self.data_length} bits")
        values = _counter_values(counters, frames.shape[0]) % self.counter_modulus
        self._counter.write_batch(frames, values)
        if self._nibble is not None:
            self._nibble.write_batch(frames, np.full(frames.shape[0], (self.data_id >> 8) & 0xF))
        frames[:, self._crc_byte] = self._crc_register(frames, values)
        return frames

    def __repr__(self) -> str:
        return (f"AutosarP01(data_id={self.data_id:#x}, data_length={self.data_length}, "
                f"data_id_mode={self.data_id_mode!r}, crc_offset={self.crc_offset}, "
                f"counter_offset={self.counter_offset}, "
                f"data_id_nibble_offset={self.data_id_nibble_offset})")


_P02_MAX_DATA_LENGTH = 8 * 256


class AutosarP02(_Profile):
    """The ``autosar_p02`` profile: AUTOSAR E2E Profile 2 (definitions: module docstring).

    Parameters
    ----------
    data_id_list : (16,) the Data IDs, bytes 0..255; the frame with counter c folds in
        ``data_id_list[c]``.
    data_length : the protected data's length in bits, a multiple of 8 in 16..2048.

    Frames shorter than ``data_length / 8`` bytes fail; bytes beyond it are not covered.

    Examples
    --------
    The worked example of autosar-e2e's tests (data 0..7, DataIDList 0..15, counter 2):

    >>> profile = make_profile({"profile": "autosar_p02", "data_id_list": list(range(16))},
    ...                        0x18FF0102, True, 8, {}, "bus.e2e.messages.Torque")
    >>> frame = profile.protect(bytes(range(8)), 2)
    >>> frame.hex(), profile.counter(frame), profile.check(frame), profile.counter_modulus
    ('bc02020304050607', 2, True, 16)
    """

    name: str = "autosar_p02"

    def __init__(self, data_id_list: Sequence[int] | bytes, data_length: int) -> None:
        values = list(data_id_list) if isinstance(data_id_list, Sequence | bytes) else None
        if (values is None or len(values) != 16
                or not all(isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= 0xFF
                           for v in values)):
            raise ConfigError("data_id_list", f"expected 16 integers in 0..255 (one Data ID "
                                              f"per counter value), got {data_id_list!r}")
        _multiple("data_length", data_length, 8)
        if not 16 <= data_length <= _P02_MAX_DATA_LENGTH:
            raise ConfigError("data_length", f"expected 16..{_P02_MAX_DATA_LENGTH} bits, got "
                                             f"{data_length}")
        self.data_id_list = bytes(values)
        self.data_length = data_length
        self.counter_modulus = 16
        self._n_bytes = data_length // 8
        self._ids_np = np.frombuffer(self.data_id_list, dtype=np.uint8)

    @classmethod
    def from_config(cls, options: Mapping[str, Any], frame_id: int, is_extended: bool,
                    length: int, signals: Mapping[str, SignalPlace], where: str) -> AutosarP02:
        """The profile from ``data_id_list`` (required) and ``data_length``."""
        given = parse_options(options, {"data_length": Option(int, 16, _P02_MAX_DATA_LENGTH)},
                              where, extra=("data_id_list",))
        if options.get("data_id_list") is None:
            raise ConfigError(f"{where}.data_id_list", "missing: the 16 Data IDs (0..255) of "
                                                       "the message, one per counter value")
        if length < _HEADER:
            raise ConfigError(where, f"profile autosar_p02 needs a message of at least 2 bytes "
                                     f"(CRC and counter), this one has {length}")
        given.setdefault("data_length", 8 * length)
        if given["data_length"] > 8 * length:
            raise ConfigError(f"{where}.data_length", f"{given['data_length']} bits do not fit "
                                                      f"the {length}-byte message")
        with _options_of(where):
            return cls(options["data_id_list"], given["data_length"])

    def _crc(self, payloads: NDArray[np.uint8], counters: NDArray[np.int64]) -> NDArray[np.uint8]:
        register = _run_columns(_TABLE_H2F_NP, CRC8H2F_INIT, payloads, range(1, self._n_bytes))
        register = _TABLE_H2F_NP[register ^ self._ids_np[counters]]
        return register ^ np.uint8(CRC8H2F_XOROUT)

    def check(self, payload: bytes) -> bool:
        if len(payload) < self._n_bytes:
            return False
        register = _register(_TABLE_H2F, CRC8H2F_INIT, payload[1 : self._n_bytes])
        register = _TABLE_H2F[register ^ self.data_id_list[payload[1] & 0xF]]
        return payload[0] == register ^ CRC8H2F_XOROUT

    def check_batch(self, payloads: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        payloads, lengths = _frames(payloads, lengths)
        if payloads.shape[1] < self._n_bytes:
            return np.zeros(payloads.shape[0], dtype=np.bool_)
        crc = self._crc(payloads, (payloads[:, 1] & 0xF).astype(np.int64))
        return (lengths >= self._n_bytes) & (crc == payloads[:, 0])

    def counters(self, payloads: np.ndarray) -> np.ndarray:
        return (_padded(payloads, _HEADER)[:, 1] & 0xF).astype(np.int64)

    def counter(self, payload: bytes) -> int:
        return _padded_bytes(payload, _HEADER)[1] & 0xF

    def protect_batch(self, payloads: np.ndarray, counters: np.ndarray) -> np.ndarray:
        frames = _protectable(payloads, self._n_bytes, f"data_length {self.data_length} bits")
        values = _counter_values(counters, frames.shape[0]) % self.counter_modulus
        frames[:, 1] = (frames[:, 1] & 0xF0) | values.astype(np.uint8)
        frames[:, 0] = self._crc(frames, values)
        return frames

    def __repr__(self) -> str:
        return (f"AutosarP02(data_id_list={list(self.data_id_list)}, "
                f"data_length={self.data_length})")


# The registry: the only place that branches on a profile's name.
PROFILES: dict[str, ProfileFactory] = {
    NoProtection.name: NoProtection.from_config,
    AliveCounter.name: AliveCounter.from_config,
    CanfdiProfile.name: CanfdiProfile.from_config,
    AutosarP01.name: AutosarP01.from_config,
    AutosarP02.name: AutosarP02.from_config,
}


def make_profile(spec: str | Mapping[str, Any], frame_id: int, is_extended: bool, length: int,
                 signals: Mapping[str, SignalPlace], where: str) -> E2EProfile:
    """The E2E profile of one message, from what the user wrote for it in the config.

    Parameters
    ----------
    spec : a profile name (``"none"``), or a mapping with the name under ``profile`` and the
        profile's options beside it (``{profile: counter, signal: Alive, modulus: 16}``).
    frame_id : the message's arbitration ID.
    is_extended : whether it is a 29-bit ID.
    length : the message's length in bytes (DBC), 0..64.
    signals : the message's signal names -> `SignalPlace` ``(start, length, byte_order)``, in
        cantools' conventions (``signal.start``, ``signal.length``, ``signal.byte_order``).
    where : the dotted config path of ``spec`` (``bus.e2e.messages.MotorFeedback``).

    Returns
    -------
    E2EProfile.

    Raises
    ------
    ConfigError
        ``where`` (or ``where.profile``) for an unknown profile name, listing the known ones and
        the nearest; ``where.<key>`` for a bad option.

    Examples
    --------
    >>> make_profile({"profile": "autosar_p1"}, 0x10, False, 8, {}, "bus.e2e.messages.M")
    Traceback (most recent call last):
    ...
    canfdi.core.settings.ConfigError: bus.e2e.messages.M.profile: unknown E2E profile \
'autosar_p1' (did you mean autosar_p01 or autosar_p02? known: autosar_p01, autosar_p02, canfdi, \
counter, none)
    """
    if not 0 <= length <= _MAX_PAYLOAD:
        raise ValueError(f"length must be in 0..{_MAX_PAYLOAD} bytes, got {length}")
    if frame_id < 0 or frame_id > (0x1FFFFFFF if is_extended else MAX_ARBITRATION_ID):
        raise ValueError(f"frame_id {frame_id:#x} is not a {29 if is_extended else 11}-bit ID")
    if isinstance(spec, str):
        name, options, name_field = spec, {}, where
    elif isinstance(spec, Mapping):
        name_field = f"{where}.profile"
        if "profile" not in spec:
            raise ConfigError(name_field, f"missing: name the E2E profile (known: "
                                          f"{', '.join(sorted(PROFILES))})")
        name = spec["profile"]
        options = {key: value for key, value in spec.items() if key != "profile"}
    else:
        raise ConfigError(where, f"expected an E2E profile name or a mapping with 'profile' "
                                 f"and its options, got {type(spec).__name__}")
    if not isinstance(name, str) or name not in PROFILES:
        raise unknown_name(name_field, "E2E profile", name, PROFILES)
    return PROFILES[name](options, frame_id, is_extended, length, signals, where)
