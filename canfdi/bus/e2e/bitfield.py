"""An unsigned field of a payload (a counter, a Data ID nibble), read and written in place."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class BitField:
    """An unsigned field of a payload, as (byte, lowest bit, width, value shift) pieces.

    Attributes
    ----------
    length : the field's width in bits.
    pieces : one ``(byte, lowest bit, width, value shift)`` per payload byte the field touches.

    Examples
    --------
    A 12-bit Intel signal from bit 4 spans the high nibble of byte 0 and all of byte 1:

    >>> field = BitField.of(4, 12, "little_endian")
    >>> field.pieces, field.n_bytes
    (((0, 4, 4, 0), (1, 0, 8, 4)), 2)
    >>> frames = np.zeros((2, 2), np.uint8)
    >>> field.write_batch(frames, np.array([0xABC, 1]))
    >>> frames.tolist(), field.read(bytes(frames[0])), field.read_batch(frames).tolist()
    ([[192, 171], [16, 0]], 2748, [2748, 1])
    """

    length: int
    pieces: tuple[tuple[int, int, int, int], ...]

    @classmethod
    def of(cls, start: int, length: int, byte_order: str) -> BitField:
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
        """The field's value in one payload (at least `n_bytes` long)."""
        value = 0
        for byte, bit, width, shift in self.pieces:
            value |= ((payload[byte] >> bit) & ((1 << width) - 1)) << shift
        return value

    def read_batch(self, payloads: NDArray[np.uint8]) -> NDArray[np.int64]:
        """(N,) the field's value in each row of (N, L >= `n_bytes`) payloads."""
        value = np.zeros(payloads.shape[0], dtype=np.int64)
        for byte, bit, width, shift in self.pieces:
            value |= ((payloads[:, byte] >> bit) & ((1 << width) - 1)).astype(np.int64) << shift
        return value

    def write_batch(self, frames: NDArray[np.uint8], values: NDArray[np.int64]) -> None:
        """Write (N,) ``values`` (their low `length` bits) into (N, L) ``frames`` in place."""
        for byte, bit, width, shift in self.pieces:
            mask = ((1 << width) - 1) << bit
            field = ((values >> shift) << bit) & mask
            frames[:, byte] = (frames[:, byte] & (0xFF ^ mask)) | field.astype(np.uint8)
