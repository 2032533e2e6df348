import numpy as np
import pytest
from scipy.linalg import expm

from canfdi.core.model import ModelError, StateSpace


def test_shapes_and_defaults():
    m = StateSpace(A=np.eye(3), B=[1, 2, 3], C=[[1, 0, 0]])
    assert (m.n, m.p, m.q, m.r, m.r1) == (3, 1, 1, 0, 0)
    assert m.B.shape == (3, 1) and m.D.shape == (1, 1) and m.F.shape == (3, 0)
    assert not m.A.flags.writeable


@pytest.mark.parametrize(
    ("kwargs", "field", "expected"),
    [
        (dict(A=[[1, 0]], B=[[1]], C=[[1]]), "A", "square"),
        (dict(A=np.eye(2), B=[[1], [2], [3]], C=[[1, 0]]), "B", "(2, any)"),
        (dict(A=np.eye(2), B=[[1], [2]], C=[[1, 0, 0]]), "C", "(q, 2)"),
        (dict(A=np.eye(2), B=[[1], [2]], C=[[1, 0]], D=[[1, 2]]), "D", "(1, 1)"),
        (dict(A=np.eye(2), B=[[1], [2]], C=[[1, 0]], F=[[1], [2], [3]]), "F", "(2, any)"),
        (dict(A=np.eye(2), B=[[1], [2]], C=[[1, 0]], G=[[1], [2]]), "G", "(1, any)"),
        (dict(A=np.eye(2), B=[[1], [2]], C=[[1, 0]], continuous=True), "dt", "sample period"),
        (dict(A=np.eye(2), B=[[1], [2]], C=[[1, 0]], dt=-1.0), "dt", "positive"),
        (dict(A=[[np.nan]], B=[[1]], C=[[1]]), "A[0][0]", "nan is not a finite number"),
        (dict(A=[[0.5, 1e308]], B=[[1]], C=[[1]]), "A[0][1]", "magnitude at most 1e+09"),
        (dict(A=np.eye(2), B=[[1], [-np.inf]], C=[[1, 0]]), "B[1][0]", "-inf"),
        (dict(A=[[0.5] * 300], B=[[1]], C=[[1]]), "A", "more than 256 rows or columns"),
        (dict(A=[[[0.5]]], B=[[1]], C=[[1]]), "A", "deeper nesting"),
    ],
)
def test_shape_errors_name_the_matrix(kwargs, field, expected):
    with pytest.raises(ModelError) as err:
        StateSpace(**kwargs)
    assert err.value.field == field
    assert expected in str(err.value)


def test_from_dict_prefixes_field_and_rejects_unknown_keys():
    with pytest.raises(ModelError) as err:
        StateSpace.from_dict({"A": [[1, 0], [0, 1]], "B": [[1, 2, 3]], "C": [[1, 0]]})
    assert err.value.field == "model.B"
    with pytest.raises(ModelError) as err:
        StateSpace.from_dict({"A": [[1]], "B": [[1]], "C": [[1]], "Q": 1})
    assert err.value.field == "model.Q"
    with pytest.raises(ModelError) as err:
        StateSpace.from_dict({"A": [[1]], "B": [[1]]})
    assert err.value.field == "model.C"
    with pytest.raises(ModelError) as err:
        StateSpace.from_dict({"A": [[1]], "B": [[1]], "C": [[1]], "time": "hybrid"})
    assert err.value.field == "model.time"


def test_zoh_discretisation_matches_matrix_exponential():
    A = np.array([[0.0, 1.0], [-2.0, -3.0]])
    B = np.array([[0.0], [1.0]])
    F = np.array([[1.0], [0.0]])
    dt = 0.1
    m = StateSpace(A=A, B=B, C=[[1, 0]], F=F, dt=dt, continuous=True).discretize()
    # Van Loan: expm([[A, BF], [0, 0]] dt) = [[Ad, BFd], [0, I]]
    M = np.zeros((4, 4))
    M[:2, :2], M[:2, 2:3], M[:2, 3:4] = A, B, F
    E = expm(M * dt)
    np.testing.assert_allclose(m.A, E[:2, :2], atol=1e-12)
    np.testing.assert_allclose(m.B, E[:2, 2:3], atol=1e-12)
    np.testing.assert_allclose(m.F, E[:2, 3:4], atol=1e-12)
    assert not m.continuous and m.dt == dt
