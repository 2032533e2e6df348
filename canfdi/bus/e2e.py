"""End-to-end (E2E) protection of CAN payloads: CRC-8 SAE J1850 and an alive counter.

Every message of canfdi's DBC files (``dbc/README.md``) carries the same two-byte header:

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

The scalar functions work on one payload; `crc8_batch`, `protect_batch` and `e2e_check_batch`
protect and check many frames at once with numpy, looping over byte columns (at most 10) and
never over frames, so a recorded log costs a few vectorised table look-ups per byte position.

References
----------
SAE J1850, *Class B Data Communications Network Interface*, CRC-8 (check value 0x4B).
AUTOSAR, *Specification of SW-C End-to-End Communication Protection Library* (Profile 1,
Data ID mode "both bytes").
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canfdi.core._check import check_shape

__all__ = [
    "CRC8_INIT",
    "CRC8_POLY",
    "CRC8_XOROUT",
    "MAX_ARBITRATION_ID",
    "UNDETECTED_ID_XORS",
    "check",
    "confusable_ids",
    "counter_delta",
    "counter_of",
    "crc8",
    "crc8_batch",
    "data_id",
    "e2e_check_batch",
    "e2e_crc",
    "protect",
    "protect_batch",
]

CRC8_POLY = 0x1D
CRC8_INIT = 0xFF
CRC8_XOROUT = 0xFF
MAX_ARBITRATION_ID = 0x7FF
# Classic CAN: a payload longer than 8 bytes is a CAN FD frame, which our DBCs do not use.
_MAX_DLC = 8
# The smallest protected payload: CRC and counter, no signals.
_HEADER = 2


def _make_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ CRC8_POLY) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


_TABLE = _make_table()
# The same table as an array so that a whole column of frames is one fancy-indexing look-up.
_TABLE_NP: NDArray[np.uint8] = np.array(_TABLE, dtype=np.uint8)
_ALL_IDS = np.arange(2048, dtype=np.int64)
# CRC register (before the final XOR) after the Data ID bytes (low, high) of every 11-bit ID.
_ID_SEEDS: NDArray[np.uint8] = _TABLE_NP[
    _TABLE_NP[CRC8_INIT ^ (_ALL_IDS & 0xFF)].astype(np.int64) ^ (_ALL_IDS >> 8)
]


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
    crc = init
    for byte in data:
        crc = _TABLE[crc ^ byte]
    return crc ^ CRC8_XOROUT


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
    # that seed (one look-up), then run its payload bytes 1..dlc-1 a DLC group at a time, so
    # no step needs a per-frame length mask.
    crc = _ID_SEEDS[ids.astype(np.int64)]
    dlc = dlc.astype(np.int64)
    for length in np.unique(dlc):
        if length < _HEADER:
            continue
        rows = np.flatnonzero(dlc == length) if len(crc) else np.zeros(0, dtype=np.int64)
        reg = crc[rows]
        for j in range(1, int(length)):
            reg = _TABLE_NP[reg ^ payloads[rows, j]]
        crc[rows] = reg
    return ((crc ^ np.uint8(CRC8_XOROUT)) == payloads[:, 0]) & (dlc >= _HEADER)


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
    counters = np.asarray(counters)
    if counters.ndim > 1 or (counters.ndim == 1 and counters.shape != (n_frames,)):
        raise ValueError(f"counters must be a scalar or have shape ({n_frames},), got "
                         f"{counters.shape}")
    if counters.size and counters.min() < 0:
        raise ValueError("counters must be >= 0")
    frames[:, 1] = np.broadcast_to(counters, (n_frames,)).astype(np.int64) & 0xFF
    message = np.empty((n_frames, frames.shape[1] + 1), dtype=np.uint8)
    message[:, 0] = ids & 0xFF
    message[:, 1] = ids >> 8
    message[:, 2:] = frames[:, 1:]
    frames[:, 0] = crc8_batch(message)
    return frames


# -- profiles (interim: none and canfdi; the e2e branch brings the registry in full) ---------

class E2EProfile(Protocol):
    """End-to-end protection of one message (see make_profile)."""

    name: str
    counter_modulus: int | None

    def check(self, payload: bytes) -> bool: ...
    def check_batch(self, payloads: np.ndarray, lengths: np.ndarray) -> np.ndarray: ...
    def counters(self, payloads: np.ndarray) -> np.ndarray | None: ...
    def counter(self, payload: bytes) -> int | None: ...
    def protect_batch(self, payloads: np.ndarray, counters: np.ndarray) -> np.ndarray: ...


class _NoProtection:
    name = "none"
    counter_modulus = None

    def check(self, payload: bytes) -> bool:
        return True

    def check_batch(self, payloads: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        return np.ones(len(payloads), dtype=bool)

    def counters(self, payloads: np.ndarray) -> np.ndarray | None:
        return None

    def counter(self, payload: bytes) -> int | None:
        return None

    def protect_batch(self, payloads: np.ndarray, counters: np.ndarray) -> np.ndarray:
        return np.array(payloads, dtype=np.uint8)


class _Canfdi:
    name = "canfdi"
    counter_modulus = 256

    def __init__(self, frame_id: int) -> None:
        self.frame_id = frame_id

    def check(self, payload: bytes) -> bool:
        return check(self.frame_id, payload)

    def check_batch(self, payloads: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        n = len(payloads)
        padded = np.zeros((n, _MAX_DLC), dtype=np.uint8)
        padded[:, : payloads.shape[1]] = payloads[:, :_MAX_DLC]
        return e2e_check_batch(np.full(n, self.frame_id), padded, lengths)

    def counters(self, payloads: np.ndarray) -> np.ndarray | None:
        return payloads[:, 1].astype(np.int64)

    def counter(self, payload: bytes) -> int | None:
        return payload[1]

    def protect_batch(self, payloads: np.ndarray, counters: np.ndarray) -> np.ndarray:
        return protect_batch(self.frame_id, payloads, counters)


PROFILES = ("none", "canfdi")


def make_profile(spec, frame_id: int, is_extended: bool, length: int, signals, where: str
                 ) -> E2EProfile:
    """The E2E profile a config spec names for one message."""
    name = spec if isinstance(spec, str) else spec.get("profile")
    if name == "none":
        return _NoProtection()
    if name == "canfdi":
        if is_extended or frame_id > MAX_ARBITRATION_ID or length < _HEADER:
            from canfdi.core.settings import ConfigError

            raise ConfigError(where, "the canfdi profile needs an 11-bit ID and >= 2 bytes")
        return _Canfdi(frame_id)
    from canfdi.core.settings import ConfigError, unknown_name

    if name is None:
        raise ConfigError(where, "expected a profile name")
    raise unknown_name(where, "E2E profile", name, PROFILES)
