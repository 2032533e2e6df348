"""The ``none`` profile: no protection, every frame passes."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from canfdi.bus.e2e.base import ProfileBase, SignalPlace, no_options
from canfdi.bus.e2e.cspec import KIND_NONE, build_spec
from canfdi.bus.e2e.payloads import checked_frames, counter_values, protectable


class NoProtection(ProfileBase):
    """The ``none`` profile: no CRC, no counter; every frame passes.

    Examples
    --------
    >>> from canfdi.bus.e2e import make_profile

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
        no_options(options, cls.name, where)
        return cls()

    def check(self, payload: bytes) -> bool:
        return True

    def check_batch(self, payloads: np.ndarray, lengths: np.ndarray) -> np.ndarray:
        payloads, lengths = checked_frames(payloads, lengths)
        return np.ones(payloads.shape[0], dtype=np.bool_)

    def counters(self, payloads: np.ndarray) -> None:
        return None

    def counter(self, payload: bytes) -> None:
        return None

    def protect_batch(self, payloads: np.ndarray, counters: np.ndarray) -> np.ndarray:
        frames = protectable(payloads, 0, "any payload")
        counter_values(counters, frames.shape[0])
        return frames

    def c_spec(self) -> tuple[np.ndarray, np.ndarray]:
        """The C core's tables: any length passes, no counter.

        Returns
        -------
        (CFDI_E2E_INTS,) int32 and (CFDI_E2E_BYTES,) uint8 (`canfdi.bus.e2e.cspec`).
        """
        return build_spec(KIND_NONE, 0)

    def __repr__(self) -> str:
        return "NoProtection()"
