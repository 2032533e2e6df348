"""The ``counter`` profile: an alive counter in a named signal, no CRC."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from canfdi.bus.e2e.base import ProfileBase, SignalPlace, options_of
from canfdi.bus.e2e.bitfield import BitField
from canfdi.bus.e2e.cspec import KIND_COUNTER, build_spec
from canfdi.bus.e2e.payloads import (
    checked_frames,
    counter_values,
    padded,
    padded_bytes,
    protectable,
)
from canfdi.core.settings import ConfigError, Option, parse_options, unknown_name

# Counters are read into int64; AUTOSAR's longest alive counter (Profile 7) has 32 bits.
_MAX_COUNTER_BITS = 32


class AliveCounter(ProfileBase):
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
    >>> from canfdi.bus.e2e import make_profile

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
        self._field = BitField.of(start, length, byte_order)

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
        with options_of(where):
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
        payloads, lengths = checked_frames(payloads, lengths)
        values = self._field.read_batch(padded(payloads, self._field.n_bytes))
        return (lengths >= self._field.n_bytes) & (values < self.counter_modulus)

    def counters(self, payloads: np.ndarray) -> np.ndarray:
        return self._field.read_batch(padded(payloads, self._field.n_bytes))

    def counter(self, payload: bytes) -> int:
        return self._field.read(padded_bytes(payload, self._field.n_bytes))

    def protect_batch(self, payloads: np.ndarray, counters: np.ndarray) -> np.ndarray:
        frames = protectable(payloads, self._field.n_bytes, f"the signal {self.signal}")
        values = counter_values(counters, frames.shape[0]) % self.counter_modulus
        self._field.write_batch(frames, values)
        return frames

    def c_spec(self) -> tuple[np.ndarray, np.ndarray]:
        """The C core's tables: the signal's field, long enough to hold it, below the modulus.

        Returns
        -------
        (CFDI_E2E_INTS,) int32 and (CFDI_E2E_BYTES,) uint8 (`canfdi.bus.e2e.cspec`).
        """
        return build_spec(KIND_COUNTER, self._field.n_bytes, counter=self._field,
                          counter_max=self.counter_modulus - 1)

    def __repr__(self) -> str:
        return (f"AliveCounter(signal={self.signal!r}, start={self.start}, length={self.length},"
                f" byte_order={self.byte_order!r}, modulus={self.counter_modulus})")
