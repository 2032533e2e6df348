"""The ``canfdi`` profile: canfdi's own CRC-8 + counter header, scalar, batch and as a profile.

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
`protect_batch` and `e2e_check_batch` protect and check many frames at once, and
`CanfdiProfile` is the same scheme bound to one message.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canfdi.bus.e2e.base import (
    HEADER_LENGTH,
    MAX_ARBITRATION_ID,
    ProfileBase,
    SignalPlace,
    no_options,
)
from canfdi.bus.e2e.bitfield import BitField
from canfdi.bus.e2e.crc import (
    CRC8_INIT,
    CRC8_XOROUT,
    TABLE,
    TABLE_NP,
    crc8,
    register_after,
    run_columns,
    run_to_length,
)
from canfdi.bus.e2e.cspec import KIND_CRC, build_spec
from canfdi.bus.e2e.payloads import byte_array, checked_frames, counter_values, padded, padded_bytes
from canfdi.core._check import check_shape
from canfdi.core.settings import ConfigError

# Classic CAN: a payload longer than 8 bytes is a CAN FD frame, which our DBCs do not use.
_MAX_DLC = 8
_ALL_IDS = np.arange(2048, dtype=np.int64)
# The counter, byte 1, as a field (for the C core's tables).
_COUNTER_FIELD = BitField.of(8, 8, "little_endian")
# CRC register (before the final XOR) after the Data ID bytes (low, high) of every 11-bit ID.
_ID_SEEDS: NDArray[np.uint8] = TABLE_NP[
    TABLE_NP[CRC8_INIT ^ (_ALL_IDS & 0xFF)].astype(np.int64) ^ (_ALL_IDS >> 8)
]


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
    if not HEADER_LENGTH <= len(payload) <= _MAX_DLC:
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
    if not HEADER_LENGTH <= len(payload) <= _MAX_DLC:
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
    if len(payload) < HEADER_LENGTH:
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
    payloads = check_shape("payloads", byte_array("payloads", payloads), ("N", _MAX_DLC))
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
    crc = run_to_length(TABLE_NP, _ID_SEEDS[ids.astype(np.int64)], payloads, dlc, 1)
    return ((crc ^ np.uint8(CRC8_XOROUT)) == payloads[:, 0]) & (dlc >= HEADER_LENGTH)


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
    frames = byte_array("payloads", payloads).copy()
    if frames.ndim != 2 or not HEADER_LENGTH <= frames.shape[1] <= _MAX_DLC:
        raise ValueError(
            f"payloads must have shape (N, dlc) with 2 <= dlc <= 8, got {frames.shape}"
        )
    n_frames = frames.shape[0]
    ids = np.broadcast_to(np.asarray(arbitration_id), (n_frames,)).astype(np.int64)
    if ids.size and (ids.min() < 0 or ids.max() > MAX_ARBITRATION_ID):
        raise ValueError("arbitration_id must be 11-bit IDs in 0..0x7FF")
    frames[:, 1] = counter_values(counters, n_frames) & 0xFF
    seeds = _ID_SEEDS[ids]
    crc = run_columns(TABLE_NP, seeds, frames, range(1, frames.shape[1]))
    frames[:, 0] = crc ^ np.uint8(CRC8_XOROUT)
    return frames


class CanfdiProfile(ProfileBase):
    """The ``canfdi`` profile: canfdi's own header (the module's docstring) for one 11-bit ID.

    Parameters
    ----------
    frame_id : the message's 11-bit arbitration ID (its Data ID), 0..0x7FF.

    Frames of 2..8 bytes; the CRC covers each frame's own length, like `check`.

    Examples
    --------
    >>> from canfdi.bus.e2e import make_profile

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
        no_options(options, cls.name, where)
        if is_extended or not 0 <= frame_id <= MAX_ARBITRATION_ID:
            raise ConfigError(where, f"profile canfdi protects 11-bit IDs only (its Data ID is "
                                     f"the 11-bit arbitration ID); this message has the 29-bit "
                                     f"ID {frame_id:#x}")
        if not HEADER_LENGTH <= length <= _MAX_DLC:
            raise ConfigError(where, f"profile canfdi needs a message of 2..8 bytes (CRC, "
                                     f"counter, signals), this one has {length}")
        return cls(frame_id)

    def check(self, payload: bytes) -> bool:
        if not HEADER_LENGTH <= len(payload) <= _MAX_DLC:
            return False
        return payload[0] == register_after(TABLE, self._seed, payload[1:]) ^ CRC8_XOROUT

    def check_batch(self, payloads: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        payloads, lengths = checked_frames(payloads, lengths)
        if payloads.shape[1] < HEADER_LENGTH:
            return np.zeros(payloads.shape[0], dtype=np.bool_)
        valid = lengths >= HEADER_LENGTH
        if payloads.shape[1] > _MAX_DLC:
            valid &= lengths <= _MAX_DLC
            lengths = np.minimum(lengths, _MAX_DLC)
        start = np.full(payloads.shape[0], self._seed, dtype=np.uint8)
        crc = run_to_length(TABLE_NP, start, payloads, lengths, 1)
        return ((crc ^ np.uint8(CRC8_XOROUT)) == payloads[:, 0]) & valid

    def counters(self, payloads: np.ndarray) -> np.ndarray:
        return padded(payloads, HEADER_LENGTH)[:, 1].astype(np.int64)

    def counter(self, payload: bytes) -> int:
        return padded_bytes(payload, HEADER_LENGTH)[1]

    def protect_batch(self, payloads: np.ndarray, counters: np.ndarray) -> np.ndarray:
        return protect_batch(self.frame_id, payloads, counters)

    def c_spec(self) -> tuple[np.ndarray, np.ndarray]:
        """The C core's tables: 2..8 bytes, counter byte 1, the CRC in byte 0 over bytes
        1 .. len - 1 from the register after the Data ID.

        Returns
        -------
        (CFDI_E2E_INTS,) int32 and (CFDI_E2E_BYTES,) uint8 (`canfdi.bus.e2e.cspec`).
        """
        return build_spec(KIND_CRC, HEADER_LENGTH, _MAX_DLC, counter=_COUNTER_FIELD,
                          counter_max=self.counter_modulus - 1, table=TABLE, seeds=(self._seed,),
                          crc_byte=0, crc_first=1, crc_to_length=True, xor_out=CRC8_XOROUT)

    def __repr__(self) -> str:
        return f"CanfdiProfile(frame_id={self.frame_id:#x})"
