"""The ``autosar_p01`` profile: AUTOSAR E2E Profile 1.

Definitions as in AUTOSAR Classic Platform R4.3.0, *Specification of SW-C End-to-End
Communication Protection Library* (SWS E2ELibrary), section 7.3 (Profile 1); the
protocol is unchanged in the later *E2E Protocol Specification* (PRS E2EProtocol, from
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

The receiver's state machine of the profile (MaxDeltaCounterInit, SyncCounterInit, ...) is not
here: a profile checks one frame and reads its counter; canfdi judges counter steps itself
(the assembler).

Sources: the AUTOSAR documents themselves were not at hand; the requirement texts cited above
are as quoted in the ``@req`` comments of ArcCore's Arctic Core ``E2E_P01.c`` and
``E2E_P02.c`` (written against R4.3.0). The tests check these profiles against an independent
implementation, the ``autosar-e2e`` package on PyPI (Artur Drogunow, MIT licence; C code,
github.com/zariiii9003/autosar-e2e), frame for frame on random data, and against the worked
examples of its own test suite; the CRCs against their published check values
(``crc8(b"123456789") == 0x4B``, ``crc8h2f(b"123456789") == 0xDF``, AUTOSAR SWS CRC Library).

References
----------
AUTOSAR CP R4.3.0, *Specification of SW-C End-to-End Communication Protection Library*
(Profiles 1 and 2); *Specification of CRC Routines* (CRC8, CRC8H2F).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from canfdi.bus.e2e.base import HEADER_LENGTH, ProfileBase, SignalPlace, check_multiple, options_of
from canfdi.bus.e2e.bitfield import BitField
from canfdi.bus.e2e.crc import TABLE, TABLE_NP, run_columns
from canfdi.bus.e2e.cspec import KIND_CRC, build_spec
from canfdi.bus.e2e.payloads import (
    checked_frames,
    counter_values,
    padded,
    padded_bytes,
    protectable,
)
from canfdi.core.settings import ConfigError, Option, parse_options, unknown_name

_P01_MODES = ("both", "alt", "low", "nibble")
# Profile 1's counter skips 0xF, the value that marks an error (SWS_E2E_00020).
_P01_INVALID_COUNTER = 0xF
_P01_MAX_DATA_LENGTH = 240


class AutosarP01(ProfileBase):
    """The ``autosar_p01`` profile: AUTOSAR E2E Profile 1 (definitions: the module's docstring).

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

    >>> from canfdi.bus.e2e import make_profile

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
        check_multiple("data_length", data_length, 8)
        if not 16 <= data_length <= _P01_MAX_DATA_LENGTH:
            raise ConfigError("data_length", f"expected 16..{_P01_MAX_DATA_LENGTH} bits (CRC "
                                             f"byte and counter .. 30 bytes), got {data_length}")
        check_multiple("crc_offset", crc_offset, 8)
        check_multiple("counter_offset", counter_offset, 4)
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
            check_multiple("data_id_nibble_offset", data_id_nibble_offset, 4)
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
        self._counter = BitField.of(counter_offset, 4, "little_endian")
        self._nibble = (BitField.of(data_id_nibble_offset, 4, "little_endian")
                        if data_id_mode == "nibble" else None)
        low, high = data_id & 0xFF, data_id >> 8
        # The register (start value 0x00) after the Data ID: [even counter, odd counter].
        seeds = {"both": (TABLE[TABLE[low] ^ high],) * 2,
                 "low": (TABLE[low],) * 2,
                 "alt": (TABLE[low], TABLE[high]),
                 "nibble": (TABLE[TABLE[low]],) * 2}[data_id_mode]
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
        if length < HEADER_LENGTH:
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
        with options_of(where):
            return cls(**given)

    def _crc_register(self, payloads: NDArray[np.uint8],
                      counters: NDArray[np.int64]) -> NDArray[np.uint8]:
        seed = (self._seeds_np[counters & 1] if self.data_id_mode == "alt"
                else self._seeds_np[0])
        return run_columns(TABLE_NP, seed, payloads, self._columns)

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
            register = TABLE[register ^ payload[j]]
        return payload[self._crc_byte] == register

    def check_batch(self, payloads: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        payloads, lengths = checked_frames(payloads, lengths)
        if payloads.shape[1] < self._n_bytes:
            return np.zeros(payloads.shape[0], dtype=np.bool_)
        counters = self._counter.read_batch(payloads)
        ok = (lengths >= self._n_bytes) & (counters != _P01_INVALID_COUNTER)
        if self._nibble is not None:
            ok &= self._nibble.read_batch(payloads) == (self.data_id >> 8) & 0xF
        return ok & (self._crc_register(payloads, counters) == payloads[:, self._crc_byte])

    def counters(self, payloads: np.ndarray) -> np.ndarray:
        return self._counter.read_batch(padded(payloads, self._counter.n_bytes))

    def counter(self, payload: bytes) -> int:
        return self._counter.read(padded_bytes(payload, self._counter.n_bytes))

    def protect_batch(self, payloads: np.ndarray, counters: np.ndarray) -> np.ndarray:
        frames = protectable(payloads, self._n_bytes, f"data_length {self.data_length} bits")
        values = counter_values(counters, frames.shape[0]) % self.counter_modulus
        self._counter.write_batch(frames, values)
        if self._nibble is not None:
            self._nibble.write_batch(frames, np.full(frames.shape[0], (self.data_id >> 8) & 0xF))
        frames[:, self._crc_byte] = self._crc_register(frames, values)
        return frames

    def c_spec(self) -> tuple[np.ndarray, np.ndarray]:
        """The C core's tables: at least data_length / 8 bytes, the counter below 15, the
        Data ID nibble (``nibble`` mode), the CRC from the seed of the counter's parity over the
        covered bytes but the CRC byte.

        Returns
        -------
        (CFDI_E2E_INTS,) int32 and (CFDI_E2E_BYTES,) uint8 (`canfdi.bus.e2e.cspec`).
        """
        return build_spec(KIND_CRC, self._n_bytes, counter=self._counter,
                          counter_max=_P01_INVALID_COUNTER - 1, extra=self._nibble,
                          extra_value=(self.data_id >> 8) & 0xF if self._nibble is not None else 0,
                          table=TABLE, seeds=self._seeds, seed_mask=1,
                          crc_byte=self._crc_byte, crc_first=0, crc_end=self._n_bytes)

    def __repr__(self) -> str:
        return (f"AutosarP01(data_id={self.data_id:#x}, data_length={self.data_length}, "
                f"data_id_mode={self.data_id_mode!r}, crc_offset={self.crc_offset}, "
                f"counter_offset={self.counter_offset}, "
                f"data_id_nibble_offset={self.data_id_nibble_offset})")
