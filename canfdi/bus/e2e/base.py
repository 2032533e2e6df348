"""What the E2E profiles share: the profile protocol, the factory signature, option helpers."""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from typing import Any, Protocol, runtime_checkable

import numpy as np

from canfdi.core.settings import ConfigError

MAX_ARBITRATION_ID = 0x7FF
# The smallest protected payload: CRC and counter, no signals.
HEADER_LENGTH = 2

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
    >>> from canfdi.bus.e2e import make_profile

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

    def c_spec(self) -> tuple[np.ndarray, np.ndarray]:
        """The profile as the C core's tables, for ``cfdi_e2e_check`` and ``cfdi_e2e_counter``
        (canfdi/_c/e2e.h; the layout: `canfdi.bus.e2e.cspec`).

        Returns
        -------
        spec : (CFDI_E2E_INTS,) int32; bytes : (CFDI_E2E_BYTES,) uint8. With them the C core
        gives ``check(payload)`` and ``counter(payload)`` (-1 for None) for any payload.
        """
        ...


ProfileFactory = Callable[[Mapping[str, Any], int, bool, int, Mapping[str, SignalPlace], str],
                          E2EProfile]
"""``factory(options, frame_id, is_extended, length, signals, where)`` -> a profile; options
are the user's spec for the message less its ``profile`` key."""


@contextmanager
def options_of(where: str) -> Iterator[None]:
    """Re-raise a constructor's ConfigError (named by option) under the spec's dotted path."""
    try:
        yield
    except ConfigError as error:
        message = str(error).removeprefix(f"{error.field}: ")
        raise ConfigError(f"{where}.{error.field}", message) from None


def no_options(options: Mapping[str, Any], name: str, where: str) -> None:
    """A ConfigError naming the first option given to a profile that takes none."""
    if options:
        key = next(iter(options))
        raise ConfigError(f"{where}.{key}", f"unknown key (profile {name} takes no options)")


def check_multiple(key: str, value: int, of: int) -> None:
    """A ConfigError naming ``key`` unless the bit count ``value`` is a multiple of ``of``."""
    if value % of:
        raise ConfigError(key, f"expected a multiple of {of} (bits), got {value}")


class ProfileBase:
    """What all profiles share: the one-payload protect, from the profile's `protect_batch`.

    Examples
    --------
    A profile that writes its counter into byte 0 gets ``protect`` for one payload:

    >>> class ByteCounter(ProfileBase):
    ...     name, counter_modulus = "byte_counter", 256
    ...     def protect_batch(self, payloads, counters):
    ...         frames = np.array(payloads, dtype=np.uint8)
    ...         frames[:, 0] = np.asarray(counters) % 256
    ...         return frames
    >>> ByteCounter().protect(b"\\x00\\x07", 258).hex()
    '0207'
    """

    name: str
    counter_modulus: int | None = None

    def protect_batch(self, payloads: np.ndarray, counters: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def protect(self, payload: bytes | bytearray, counter: int) -> bytes:
        """Sender side for one payload: `protect_batch` of one row, as bytes."""
        row = np.frombuffer(bytes(payload), dtype=np.uint8)[None, :]
        return self.protect_batch(row, np.array([counter], dtype=np.int64))[0].tobytes()
