"""The one shape check: arrays are checked where they enter, with a message that names the array
and gives both shapes (as python-control's ``_check_shape`` does).

>>> import numpy as np
>>> check_shape("payloads", np.zeros((3, 7)), ("N", 8))
Traceback (most recent call last):
...
ValueError: payloads: expected shape (N, 8), got (3, 7)
>>> check_shape("P", np.eye(2), ("d", "d")).shape
(2, 2)
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, DTypeLike

__all__ = ["check_shape"]


def _spelled(shape: Sequence[int | str]) -> str:
    inner = ", ".join(str(d) for d in shape)
    return f"({inner},)" if len(shape) == 1 else f"({inner})"


def check_shape(name: str, value: ArrayLike, shape: Sequence[int | str], *,
                dtype: DTypeLike | None = None, integer: bool = False, finite: bool = False,
                copy: bool = False) -> np.ndarray:
    """``value`` as an array of ``shape``, or a ValueError naming ``name`` and both shapes.

    Parameters
    ----------
    name : how the caller's documentation names the array (``"payloads"``, ``"model.C"``).
    value : the array (anything numpy takes).
    shape : one entry per dimension: an int must match; a string (``"N"``, ``"m"``) is a
        free size named in the message, and the same string twice must be the same size.
    dtype : convert to this dtype (no conversion when None).
    integer : the values must be of an integer dtype (before any conversion).
    finite : no NaN or infinity.
    copy : return a copy even when no conversion was needed.

    Returns
    -------
    ndarray of ``shape``.
    """
    array = np.array(value, copy=copy) if copy else np.asarray(value)
    sizes: dict[str, int] = {}
    ok = array.ndim == len(shape)
    if ok:
        for want, got in zip(shape, array.shape, strict=True):
            if isinstance(want, str):
                ok = sizes.setdefault(want, got) == got
            else:
                ok = want == got
            if not ok:
                break
    if not ok:
        raise ValueError(f"{name}: expected shape {_spelled(shape)}, got {_spelled(array.shape)}")
    if integer and array.size and not np.issubdtype(array.dtype, np.integer):
        raise ValueError(f"{name}: expected integers, got dtype {array.dtype}")
    if dtype is not None:
        array = array.astype(dtype, copy=False)
    if finite and not np.all(np.isfinite(array)):
        raise ValueError(f"{name}: must be finite")
    return array
