"""Blocks of payloads as the profiles take them: bytes checked, lengths and counters checked."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canfdi.core._check import check_shape


def byte_array(name: str, value: ArrayLike) -> NDArray[np.uint8]:
    """``value`` as uint8, unchanged when it already is; a ValueError naming ``name`` when it
    holds anything but integers in 0..255."""
    array = np.asarray(value)
    if array.dtype == np.uint8:
        return array
    if array.size and (
        not np.issubdtype(array.dtype, np.integer) or array.min() < 0 or array.max() > 0xFF
    ):
        raise ValueError(f"{name} must hold bytes (integers in 0..255)")
    return array.astype(np.uint8)


def checked_frames(payloads: ArrayLike,
                   lengths: ArrayLike) -> tuple[NDArray[np.uint8], NDArray[np.int64]]:
    """Validated (N, L) uint8 payloads and (N,) int64 lengths in 0..L."""
    payloads = check_shape("payloads", byte_array("payloads", payloads), ("N", "L"))
    lengths = check_shape("lengths", lengths, (payloads.shape[0],))
    if lengths.size and not np.issubdtype(lengths.dtype, np.integer):
        raise ValueError(f"lengths must be integers, got dtype {lengths.dtype}")
    if lengths.size and (lengths.min() < 0 or lengths.max() > payloads.shape[1]):
        raise ValueError(f"lengths must be in 0..{payloads.shape[1]} (the payloads' width)")
    return payloads, lengths.astype(np.int64)


def padded(payloads: ArrayLike, width: int) -> NDArray[np.uint8]:
    """(N, >= width) uint8: the payloads, zero-padded on the right when narrower."""
    payloads = check_shape("payloads", byte_array("payloads", payloads), ("N", "L"))
    if payloads.shape[1] >= width:
        return payloads
    wider = np.zeros((payloads.shape[0], width), dtype=np.uint8)
    wider[:, : payloads.shape[1]] = payloads
    return wider


def padded_bytes(payload: bytes | bytearray, width: int) -> bytes:
    """The payload, zero-padded on the right to ``width`` bytes when shorter."""
    return bytes(payload).ljust(width, b"\x00")


def protectable(payloads: ArrayLike, width: int, what: str) -> NDArray[np.uint8]:
    """A copy of (N, L) payloads with L >= width, for a sender to write into."""
    frames = byte_array("payloads", payloads)
    if frames.ndim != 2 or frames.shape[1] < width:
        raise ValueError(f"payloads must have shape (N, L) with L >= {width} ({what}), got "
                         f"{frames.shape}")
    return frames.copy()


def counter_values(counters: ArrayLike, n_frames: int) -> NDArray[np.int64]:
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
