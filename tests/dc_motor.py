"""The Chan et al. 2006 DC motor model used by several test layers (b2 = 0.0823, see the errata)."""

import numpy as np

from canfdi.core.model import StateSpace

A = np.diag([0.8825, 0.6839, 0.9948])
B = np.array([[0.002235], [0.0823], [0.0]])
C = np.array([[1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 0, 1]], dtype=float)
F = np.array([[0, 0], [1, 0], [0, 1]], dtype=float)


def dc_motor() -> StateSpace:
    return StateSpace(A=A, B=B, C=C, F=F, dt=0.01)
