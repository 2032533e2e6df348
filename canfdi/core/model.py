"""State-space models with known linear part and structured unknown inputs.

The model is Chan et al. 2006, eq. (1)::

    x(k+1) = A x(k) + B u(k) + F w(k)          (or dx/dt = ... in continuous time)
    y(k)   = C x(k) + D u(k) + G psi(k)

with x of size n, u of size p, y of size q, w of size r (state unknown input, entering through F)
and psi of size r1 (output unknown input, entering through G). D is optional (zero in Chan et al.
2006).

A continuous model carries a sample period ``dt`` and is discretised with a zero-order hold
(`zoh`, the matrix exponential, as scipy.signal.cont2discrete does it); the unknown input w
is discretised as if it were held over the period too, which is what makes F a valid
distribution matrix for the sampled w(k).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.linalg import expm

from canfdi.core._check import check_shape

__all__ = ["ModelError", "StateSpace", "zoh"]


def zoh(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order hold of dx/dt = A x + B u over ``dt`` (u held): (Ad (n, n), Bd (n, m)),
    read off the exponential of the augmented matrix [[A, B], [0, 0]] dt.

    >>> Ad, Bd = zoh(np.array([[-2.0]]), np.array([[2.0]]), 0.5)
    >>> round(float(Ad[0, 0]), 6), round(float(Bd[0, 0]), 6)
    (0.367879, 0.632121)
    """
    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = A, B
    E = expm(M * dt)
    return E[:n, :n], E[:n, n:]


class ModelError(ValueError):
    """A model matrix has the wrong shape or content; ``field`` names it.

    Examples
    --------
    >>> try:
    ...     StateSpace(A=[[0.9]], B=[[1.0]], C=[[1.0, 2.0]])
    ... except ModelError as exc:
    ...     print(exc.field, "|", exc)
    C | C: expected shape (q, 1), got (1, 2) (transposed?)
    """

    def __init__(self, field_name: str, message: str) -> None:
        super().__init__(f"{field_name}: {message}")
        self.field = field_name


MAX_DIMENSION = 256
"""The most rows or columns a model matrix may have (states, inputs, outputs): checked before
anything is allocated, so that a config (a YAML alias repeated) cannot ask for gigabytes."""

MAX_ENTRY = 1e9
"""The largest magnitude of a model matrix entry: beyond it products over a parity window
overflow float64, and no drive's model needs it."""


def _matrix(value: Any, name: str) -> np.ndarray:
    if isinstance(value, list | tuple):
        if len(value) > MAX_DIMENSION or any(
                isinstance(row, list | tuple) and len(row) > MAX_DIMENSION for row in value):
            raise ModelError(name, f"more than {MAX_DIMENSION} rows or columns")
        if any(isinstance(row, list | tuple) and any(isinstance(x, list | tuple | dict)
                                                      for x in row) for row in value):
            raise ModelError(name, "expected a 2-D matrix (a list of rows of numbers), got "
                                   "deeper nesting")
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ModelError(name, f"not a numeric matrix ({exc})") from None
    if arr.ndim == 1:
        # A flat list is a column for B, F and friends only when it cannot be a row; the caller
        # states the expected shape, so keep it a row here and let the shape check decide.
        arr = arr.reshape(1, -1) if arr.size else arr.reshape(0, 0)
    if arr.ndim != 2:
        raise ModelError(name, f"expected a 2-D matrix, got {arr.ndim} dimensions")
    if arr.size > MAX_DIMENSION ** 2:
        raise ModelError(name, f"more than {MAX_DIMENSION} rows or columns")
    bad = np.argwhere(~np.isfinite(arr) | (np.abs(np.nan_to_num(arr)) > MAX_ENTRY))
    if len(bad):
        i, j = bad[0]
        raise ModelError(f"{name}[{i}][{j}]", f"{float(arr[i, j])!r} is not a finite number of "
                                              f"magnitude at most {MAX_ENTRY:g}")
    return arr


def _shaped(value: Any, name: str, rows: int, cols: int | None) -> np.ndarray:
    """Coerce ``value`` to a (rows, cols) matrix; cols=None means any number of columns."""
    if value is None:
        return np.zeros((rows, 0 if cols is None else cols))
    arr = _matrix(value, name)
    if arr.size == 0:
        return np.zeros((rows, 0 if cols is None else cols))
    # A flat list given for a single-column matrix (B with one input, say) is the column.
    if arr.shape[0] == 1 and rows != 1 and arr.shape[1] == rows and cols in (None, 1):
        arr = arr.T
    try:
        return check_shape(name, arr, (rows, "any" if cols is None else cols))
    except ValueError as exc:  # the config names the matrix: model.B, not B
        raise ModelError(name, str(exc).split(": ", 1)[1]) from None


@dataclass(frozen=True)
class StateSpace:
    """A linear model with unknown-input distributions, discrete or continuous.

    Parameters
    ----------
    A : (n, n) state matrix.
    B : (n, p) input matrix.
    C : (q, n) output matrix.
    D : (q, p) feedthrough; zeros when not given.
    F : (n, r) distribution of the state unknown input w; (n, 0) when there is none.
    G : (q, r1) distribution of the output unknown input psi; (q, 0) when there is none.
    dt : sample period in seconds; required for a continuous model.
    continuous : True when A, B, F describe dx/dt rather than x(k+1).

    Examples
    --------
    >>> motor = StateSpace(A=[[-2.0]], B=[[1.0]], C=[[1.0]], F=[[1.0]], dt=0.1,
    ...                    continuous=True)
    >>> (motor.n, motor.p, motor.q, motor.r), motor.D
    ((1, 1, 1, 1), array([[0.]]))
    >>> discrete = motor.discretize()
    >>> discrete.continuous, np.round(discrete.A, 4), np.round(discrete.B, 4)
    (False, array([[0.8187]]), array([[0.0906]]))
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray = field(default=None)  # type: ignore[assignment]
    F: np.ndarray = field(default=None)  # type: ignore[assignment]
    G: np.ndarray = field(default=None)  # type: ignore[assignment]
    dt: float | None = None
    continuous: bool = False

    def __post_init__(self) -> None:
        A = _matrix(self.A, "A")
        if A.shape[0] != A.shape[1] or A.shape[0] == 0:
            raise ModelError("A", f"expected a square (n, n) matrix with n >= 1, got {A.shape}")
        n = A.shape[0]
        B = _shaped(self.B, "B", n, None)
        C = _matrix(self.C, "C")
        if C.shape[1] != n:
            if C.shape[0] == n and C.shape[1] != n and C.shape[0] != C.shape[1]:
                raise ModelError("C", f"expected shape (q, {n}), got {C.shape} (transposed?)")
            raise ModelError("C", f"expected shape (q, {n}), got {C.shape}")
        q, p = C.shape[0], B.shape[1]
        D = _shaped(self.D, "D", q, p)
        F = _shaped(self.F, "F", n, None)
        G = _shaped(self.G, "G", q, None)
        if self.dt is not None and not (np.isfinite(self.dt) and self.dt > 0):
            raise ModelError("dt", f"must be a positive number of seconds, got {self.dt!r}")
        if self.continuous and self.dt is None:
            raise ModelError("dt", "a continuous model needs a sample period dt for the monitor")
        for name, arr in (("A", A), ("B", B), ("C", C), ("D", D), ("F", F), ("G", G)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @property
    def n(self) -> int:
        """Number of states."""
        return self.A.shape[0]

    @property
    def p(self) -> int:
        """Number of inputs (actuators)."""
        return self.B.shape[1]

    @property
    def q(self) -> int:
        """Number of outputs (sensors)."""
        return self.C.shape[0]

    @property
    def r(self) -> int:
        """Size of the state unknown input w."""
        return self.F.shape[1]

    @property
    def r1(self) -> int:
        """Size of the output unknown input psi."""
        return self.G.shape[1]

    def discretize(self) -> StateSpace:
        """The zero-order-hold discretisation at ``dt``; a discrete model returns itself.

        Returns
        -------
        StateSpace with continuous=False and the same dt, C, D and G.
        """
        if not self.continuous:
            return self
        Ad, BFd = zoh(self.A, np.hstack([self.B, self.F]), self.dt)
        return StateSpace(
            A=Ad, B=BFd[:, : self.p], C=self.C, D=self.D, F=BFd[:, self.p :], G=self.G,
            dt=self.dt, continuous=False,
        )

    @classmethod
    def from_dict(cls, data: dict[str, Any], prefix: str = "model") -> StateSpace:
        """Build a model from a mapping (a YAML ``model:`` section).

        Keys: A, B, C (required), D, F, G (optional), ``time`` ("discrete" or "continuous",
        default discrete) and ``dt`` (seconds). Errors name the field as ``prefix.KEY``.
        """
        if not isinstance(data, dict):
            raise ModelError(prefix, "expected a mapping with A, B, C and optional D, F, G, dt")
        known = {"A", "B", "C", "D", "F", "G", "dt", "time"}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ModelError(f"{prefix}.{unknown[0]}", f"unknown key (allowed: {sorted(known)})")
        for key in ("A", "B", "C"):
            if key not in data:
                raise ModelError(f"{prefix}.{key}", "missing")
        time = data.get("time", "discrete")
        if time not in ("discrete", "continuous"):
            raise ModelError(f"{prefix}.time", f"must be 'discrete' or 'continuous', got {time!r}")
        dt = data.get("dt")
        if dt is not None and (isinstance(dt, bool) or not isinstance(dt, int | float)):
            raise ModelError(f"{prefix}.dt", f"must be a number of seconds, got {dt!r}")
        try:
            return cls(
                A=data["A"], B=data["B"], C=data["C"], D=data.get("D"), F=data.get("F"),
                G=data.get("G"), dt=None if dt is None else float(dt),
                continuous=time == "continuous",
            )
        except ModelError as exc:
            raise ModelError(f"{prefix}.{exc.field}", str(exc).split(": ", 1)[1]) from None
