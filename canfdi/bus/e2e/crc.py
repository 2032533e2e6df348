"""CRC-8 SAE J1850 and AUTOSAR's CRC-8H2F: the tables and register runs every profile uses.

Batch forms
-----------
Every batch form loops over byte columns (a few, at most the payload length) and never over
frames: a block of frames costs one vectorised table look-up per byte position.

References
----------
SAE J1850, *Class B Data Communications Network Interface*, CRC-8 (check value 0x4B).
AUTOSAR CP R4.3.0, *Specification of CRC Routines* (CRC8, CRC8H2F).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from canfdi.bus.e2e.payloads import byte_array
from canfdi.core._check import check_shape

CRC8_POLY = 0x1D
CRC8_INIT = 0xFF
CRC8_XOROUT = 0xFF
# AUTOSAR's CRC8H2F (SWS CRC Library): check value 0xDF.
CRC8H2F_POLY = 0x2F
CRC8H2F_INIT = 0xFF
CRC8H2F_XOROUT = 0xFF


def _make_table(poly: int) -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


TABLE = _make_table(CRC8_POLY)
TABLE_H2F = _make_table(CRC8H2F_POLY)
# The same tables as arrays so that a whole column of frames is one fancy-indexing look-up.
TABLE_NP: NDArray[np.uint8] = np.array(TABLE, dtype=np.uint8)
TABLE_H2F_NP: NDArray[np.uint8] = np.array(TABLE_H2F, dtype=np.uint8)


def register_after(table: tuple[int, ...], register: int, data: bytes | bytearray) -> int:
    """A CRC-8 register (MSB first, no reflection) after ``data``, from ``register``."""
    for byte in data:
        register = table[register ^ byte]
    return register


def run_columns(table: NDArray[np.uint8], register: NDArray[np.uint8] | int,
                 payloads: NDArray[np.uint8], columns: Sequence[int]) -> NDArray[np.uint8]:
    """(N,) registers after the byte ``columns`` of every row of (N, L) ``payloads``."""
    reg = np.broadcast_to(np.asarray(register, dtype=np.uint8), payloads.shape[:1])
    for j in columns:
        reg = table[reg ^ payloads[:, j]]
    return np.array(reg, dtype=np.uint8)


def run_to_length(table: NDArray[np.uint8], register: NDArray[np.uint8],
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
    return register_after(TABLE, init, data) ^ CRC8_XOROUT


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
    return register_after(TABLE_H2F, init, data) ^ CRC8H2F_XOROUT


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
    data = check_shape("data", byte_array("data", data), ("N", "L"))
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
        updated = TABLE_NP[crc ^ data[:, j]]
        crc = updated if lengths is None else np.where(j < lengths, updated, crc)
    return crc ^ np.uint8(CRC8_XOROUT)
