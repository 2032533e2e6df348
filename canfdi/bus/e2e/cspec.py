"""A profile as the C core's flat tables: this module mirrors canfdi/_c/e2e.h.

The C routine ``cfdi_e2e_check`` / ``cfdi_e2e_counter`` (canfdi/_c/e2e.c) checks a payload and
reads its alive counter from two rows a profile compiles itself into (its ``c_spec()``): an
int32 ``spec`` of `E2E_H` ``["CFDI_E2E_INTS"]`` numbers and a uint8 ``bytes`` of
``["CFDI_E2E_BYTES"]`` (the CRC's table, the seeds, the trailing bytes). This module is the
one place in Python that knows the layout; `E2E_H` holds e2e.h's ``#define`` values (a test
reads the header and compares), and `build_spec` writes the rows from named parts.

What a frame must pass, in these terms (e2e.h says it in full):

1. ``min_length <= len <= max_length``;
2. a counter (any profile but ``none``): its value <= ``counter_max``; an ``extra`` field (if
   any) == ``extra_value``;
3. a CRC: byte ``crc_byte`` == the register run with ``table`` from
   ``seeds[counter & seed_mask]`` over bytes ``crc_first .. end - 1`` (``end``: ``crc_end``,
   or the frame's length with ``crc_to_length``) except ``crc_byte``, then over
   ``trail[counter & trail_mask]`` (when ``trail`` is given), XORed with ``xor_out``.

The counter reads a payload as zero-padded.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from canfdi.bus.e2e.bitfield import BitField

__all__ = ["ANY_LENGTH", "E2E_H", "KIND_COUNTER", "KIND_CRC", "KIND_NONE", "build_spec"]

# e2e.h's indices, sizes and codes (a test reads them from the header and compares).
E2E_H: dict[str, int] = {
    "CFDI_E2E_KIND_NONE": 0, "CFDI_E2E_KIND_COUNTER": 1, "CFDI_E2E_KIND_CRC": 2,
    "CFDI_E2E_ANY_LENGTH": 2**31 - 1,
    "CFDI_E2E_PIECES": 5, "CFDI_E2E_PIECE_INTS": 4, "CFDI_E2E_PIECE_BYTE": 0,
    "CFDI_E2E_PIECE_BIT": 1, "CFDI_E2E_PIECE_WIDTH": 2, "CFDI_E2E_PIECE_SHIFT": 3,
    "CFDI_E2E_KIND": 0, "CFDI_E2E_MIN_LEN": 1, "CFDI_E2E_MAX_LEN": 2,
    "CFDI_E2E_COUNTER_MAX_HI": 3, "CFDI_E2E_COUNTER_MAX_LO": 4,
    "CFDI_E2E_COUNTER_PIECES": 5, "CFDI_E2E_COUNTER_AT": 6,
    "CFDI_E2E_EXTRA_PIECES": 26, "CFDI_E2E_EXTRA_AT": 27,
    "CFDI_E2E_EXTRA_VALUE_HI": 47, "CFDI_E2E_EXTRA_VALUE_LO": 48,
    "CFDI_E2E_CRC_BYTE": 49, "CFDI_E2E_CRC_FIRST": 50, "CFDI_E2E_CRC_END": 51,
    "CFDI_E2E_CRC_TO_LENGTH": 52, "CFDI_E2E_SEED_MASK": 53, "CFDI_E2E_TRAIL": 54,
    "CFDI_E2E_TRAIL_MASK": 55, "CFDI_E2E_XOR_OUT": 56, "CFDI_E2E_INTS": 57,
    "CFDI_E2E_TABLE": 0, "CFDI_E2E_SEEDS": 256, "CFDI_E2E_N_SEEDS": 16,
    "CFDI_E2E_TRAILS": 272, "CFDI_E2E_N_TRAILS": 16, "CFDI_E2E_BYTES": 288,
}
_H = E2E_H
KIND_NONE = _H["CFDI_E2E_KIND_NONE"]
KIND_COUNTER = _H["CFDI_E2E_KIND_COUNTER"]
KIND_CRC = _H["CFDI_E2E_KIND_CRC"]
ANY_LENGTH = _H["CFDI_E2E_ANY_LENGTH"]
_HALF = 16


def _write_field(spec: NDArray[np.int32], count_at: int, at: int, field: BitField) -> None:
    if len(field.pieces) > _H["CFDI_E2E_PIECES"]:
        raise ValueError(f"a field of {len(field.pieces)} pieces does not fit "
                         f"{_H['CFDI_E2E_PIECES']}")
    spec[count_at] = len(field.pieces)
    for k, piece in enumerate(field.pieces):
        start = at + k * _H["CFDI_E2E_PIECE_INTS"]
        spec[start: start + _H["CFDI_E2E_PIECE_INTS"]] = piece


def _write_halves(spec: NDArray[np.int32], high: int, value: int) -> None:
    if not 0 <= value < 1 << 2 * _HALF:
        raise ValueError(f"a value of the table must be in 0..2**32 - 1, got {value}")
    spec[high] = value >> _HALF
    spec[high + 1] = value & ((1 << _HALF) - 1)


def _write_bytes(table: NDArray[np.uint8], at: str, size: str, values: Sequence[int]) -> None:
    if len(values) > _H[size]:
        raise ValueError(f"{len(values)} values do not fit {size} = {_H[size]}")
    table[_H[at]: _H[at] + len(values)] = list(values)


def build_spec(kind: int, min_length: int, max_length: int = ANY_LENGTH, *,
               counter: BitField | None = None, counter_max: int = 0,
               extra: BitField | None = None, extra_value: int = 0,
               table: Sequence[int] | None = None, seeds: Sequence[int] = (),
               seed_mask: int = 0, crc_byte: int = 0, crc_first: int = 0, crc_end: int = 0,
               crc_to_length: bool = False, trail: Sequence[int] | None = None,
               trail_mask: int = 0, xor_out: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A profile's rows ``(spec, bytes)`` for ``cfdi_e2e_check`` and ``cfdi_e2e_counter``.

    Parameters
    ----------
    kind : `KIND_NONE`, `KIND_COUNTER` or `KIND_CRC`; the parts a kind does not have must be
        left at their defaults (they are written as 0).
    min_length, max_length : the payload lengths that may pass, bytes (`ANY_LENGTH`: no upper
        bound).
    counter : the alive counter's field; counter_max : the largest value that passes
        (``counter_modulus - 1``).
    extra, extra_value : a field that must hold ``extra_value`` (AUTOSAR P01's Data ID
        nibble), or None.
    table : the CRC's 256-entry table (``register = table[register ^ byte]``).
    seeds, seed_mask : start registers (at most ``CFDI_E2E_N_SEEDS``); a frame starts from
        ``seeds[counter & seed_mask]``.
    crc_byte : the byte holding the CRC; crc_first, crc_end : the bytes the CRC covers
        (``crc_byte`` skipped), or from ``crc_first`` to the frame's length with
        ``crc_to_length`` (then crc_end is 0).
    trail, trail_mask : bytes (at most ``CFDI_E2E_N_TRAILS``), one of which,
        ``trail[counter & trail_mask]``, the CRC covers after the data; or None.
    xor_out : the CRC's final XOR.

    Returns
    -------
    spec : (CFDI_E2E_INTS,) int32; bytes : (CFDI_E2E_BYTES,) uint8. Values are written as
    given (the C core checks the table; this builder does not judge it).

    Examples
    --------
    An 8-bit counter in byte 1 of frames of 2 bytes or more, counting 0..99:

    >>> spec, table = build_spec(KIND_COUNTER, 2, counter=BitField.of(8, 8, "little_endian"),
    ...                          counter_max=99)
    >>> spec[:12].tolist(), table.shape
    ([1, 2, 2147483647, 0, 99, 1, 1, 0, 8, 0, 0, 0], (288,))
    """
    spec = np.zeros(_H["CFDI_E2E_INTS"], dtype=np.int32)
    data = np.zeros(_H["CFDI_E2E_BYTES"], dtype=np.uint8)
    spec[_H["CFDI_E2E_KIND"]] = kind
    spec[_H["CFDI_E2E_MIN_LEN"]] = min_length
    spec[_H["CFDI_E2E_MAX_LEN"]] = max_length
    if counter is not None:
        _write_field(spec, _H["CFDI_E2E_COUNTER_PIECES"], _H["CFDI_E2E_COUNTER_AT"], counter)
    _write_halves(spec, _H["CFDI_E2E_COUNTER_MAX_HI"], counter_max)
    if extra is not None:
        _write_field(spec, _H["CFDI_E2E_EXTRA_PIECES"], _H["CFDI_E2E_EXTRA_AT"], extra)
    _write_halves(spec, _H["CFDI_E2E_EXTRA_VALUE_HI"], extra_value)
    if table is not None:
        if len(table) != 256:
            raise ValueError(f"a CRC table has 256 entries, got {len(table)}")
        data[_H["CFDI_E2E_TABLE"]: _H["CFDI_E2E_TABLE"] + 256] = table
    _write_bytes(data, "CFDI_E2E_SEEDS", "CFDI_E2E_N_SEEDS", seeds)
    if trail is not None:
        _write_bytes(data, "CFDI_E2E_TRAILS", "CFDI_E2E_N_TRAILS", trail)
        spec[_H["CFDI_E2E_TRAIL"]] = 1
    spec[_H["CFDI_E2E_SEED_MASK"]] = seed_mask
    spec[_H["CFDI_E2E_TRAIL_MASK"]] = trail_mask
    spec[_H["CFDI_E2E_CRC_BYTE"]] = crc_byte
    spec[_H["CFDI_E2E_CRC_FIRST"]] = crc_first
    spec[_H["CFDI_E2E_CRC_END"]] = crc_end
    spec[_H["CFDI_E2E_CRC_TO_LENGTH"]] = int(crc_to_length)
    spec[_H["CFDI_E2E_XOR_OUT"]] = xor_out
    return spec, data
