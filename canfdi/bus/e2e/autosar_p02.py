"""The ``autosar_p02`` profile: AUTOSAR E2E Profile 2.

Definitions as in AUTOSAR Classic Platform R4.3.0, *Specification of SW-C End-to-End
Communication Protection Library* (SWS E2ELibrary), section 7.4 (Profile 2); the
protocol is unchanged in the later *E2E Protocol Specification* (PRS E2EProtocol, from
R19-11). Option names are AUTOSAR's configuration names in snake case.

Profile 2 (`AutosarP02`; E2E_P02ConfigType):

* CRC-8H2F (polynomial 0x2F, start value and final XOR 0xFF; SWS_E2E_00117, SWS_E2E_00118) over
  data bytes ``1 .. data_length/8 - 1``, then the one-byte Data ID ``data_id_list[counter]``
  (SWS_E2E_00119, SWS_E2E_00120, SWS_E2E_00132, SWS_E2E_00140);
* the CRC is byte 0, the counter the low nibble of byte 1 (SWS_E2E_00122, SWS_E2E_00123; not
  configurable, SWS_E2E_00152), counting 0..15 (SWS_E2E_00128);
* options: ``data_id_list`` (16 bytes, required), ``data_length`` (default: the message's).

The receiver's state machine is not here, and the sources and references are those of Profile 1:
see canfdi.bus.e2e.autosar_p01.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from canfdi.bus.e2e.base import HEADER_LENGTH, ProfileBase, SignalPlace, check_multiple, options_of
from canfdi.bus.e2e.bitfield import BitField
from canfdi.bus.e2e.crc import (
    CRC8H2F_INIT,
    CRC8H2F_XOROUT,
    TABLE_H2F,
    TABLE_H2F_NP,
    register_after,
    run_columns,
)
from canfdi.bus.e2e.cspec import KIND_CRC, build_spec
from canfdi.bus.e2e.payloads import (
    checked_frames,
    counter_values,
    padded,
    padded_bytes,
    protectable,
)
from canfdi.core.settings import ConfigError, Option, parse_options

_P02_MAX_DATA_LENGTH = 8 * 256
# The counter, the low nibble of byte 1, as a field (for the C core's tables).
_COUNTER_FIELD = BitField.of(8, 4, "little_endian")


class AutosarP02(ProfileBase):
    """The ``autosar_p02`` profile: AUTOSAR E2E Profile 2 (definitions: the module's docstring).

    Parameters
    ----------
    data_id_list : (16,) the Data IDs, bytes 0..255; the frame with counter c folds in
        ``data_id_list[c]``.
    data_length : the protected data's length in bits, a multiple of 8 in 16..2048.

    Frames shorter than ``data_length / 8`` bytes fail; bytes beyond it are not covered.

    Examples
    --------
    The worked example of autosar-e2e's tests (data 0..7, DataIDList 0..15, counter 2):

    >>> from canfdi.bus.e2e import make_profile

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
        check_multiple("data_length", data_length, 8)
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
        if length < HEADER_LENGTH:
            raise ConfigError(where, f"profile autosar_p02 needs a message of at least 2 bytes "
                                     f"(CRC and counter), this one has {length}")
        given.setdefault("data_length", 8 * length)
        if given["data_length"] > 8 * length:
            raise ConfigError(f"{where}.data_length", f"{given['data_length']} bits do not fit "
                                                      f"the {length}-byte message")
        with options_of(where):
            return cls(options["data_id_list"], given["data_length"])

    def _crc(self, payloads: NDArray[np.uint8], counters: NDArray[np.int64]) -> NDArray[np.uint8]:
        register = run_columns(TABLE_H2F_NP, CRC8H2F_INIT, payloads, range(1, self._n_bytes))
        register = TABLE_H2F_NP[register ^ self._ids_np[counters]]
        return register ^ np.uint8(CRC8H2F_XOROUT)

    def check(self, payload: bytes) -> bool:
        if len(payload) < self._n_bytes:
            return False
        register = register_after(TABLE_H2F, CRC8H2F_INIT, payload[1 : self._n_bytes])
        register = TABLE_H2F[register ^ self.data_id_list[payload[1] & 0xF]]
        return payload[0] == register ^ CRC8H2F_XOROUT

    def check_batch(self, payloads: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        payloads, lengths = checked_frames(payloads, lengths)
        if payloads.shape[1] < self._n_bytes:
            return np.zeros(payloads.shape[0], dtype=np.bool_)
        crc = self._crc(payloads, (payloads[:, 1] & 0xF).astype(np.int64))
        return (lengths >= self._n_bytes) & (crc == payloads[:, 0])

    def counters(self, payloads: np.ndarray) -> np.ndarray:
        return (padded(payloads, HEADER_LENGTH)[:, 1] & 0xF).astype(np.int64)

    def counter(self, payload: bytes) -> int:
        return padded_bytes(payload, HEADER_LENGTH)[1] & 0xF

    def protect_batch(self, payloads: np.ndarray, counters: np.ndarray) -> np.ndarray:
        frames = protectable(payloads, self._n_bytes, f"data_length {self.data_length} bits")
        values = counter_values(counters, frames.shape[0]) % self.counter_modulus
        frames[:, 1] = (frames[:, 1] & 0xF0) | values.astype(np.uint8)
        frames[:, 0] = self._crc(frames, values)
        return frames

    def c_spec(self) -> tuple[np.ndarray, np.ndarray]:
        """The C core's tables: at least data_length / 8 bytes, the CRC-8H2F in byte 0
        over bytes 1 .. data_length / 8 - 1, then over ``data_id_list[counter]``.

        Returns
        -------
        (CFDI_E2E_INTS,) int32 and (CFDI_E2E_BYTES,) uint8 (`canfdi.bus.e2e.cspec`).
        """
        return build_spec(KIND_CRC, self._n_bytes, counter=_COUNTER_FIELD,
                          counter_max=self.counter_modulus - 1, table=TABLE_H2F,
                          seeds=(CRC8H2F_INIT,), crc_byte=0, crc_first=1, crc_end=self._n_bytes,
                          trail=self.data_id_list, trail_mask=0xF, xor_out=CRC8H2F_XOROUT)

    def __repr__(self) -> str:
        return (f"AutosarP02(data_id_list={list(self.data_id_list)}, "
                f"data_length={self.data_length})")
