"""A diagnosis' regressors and information sums on the C kernel (cfdi_info_block) against the
numpy reference (canfdi.methods.parity.hypotheses.information_increments): random banks,
every kind of hypothesis, onsets before, inside and after the window, lost commands and
residuals; bad tables refused. (The conformance suite runs whole diagnoses on both kernels.)"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from canfdi.core import kernel
from canfdi.core.kernel import info_work
from canfdi.methods.parity.hypotheses import (
    Hypothesis,
    information_increments,
    regressor_columns,
)

pytestmark = pytest.mark.skipif("c" not in kernel.available(), reason="no C kernel built here")


def _case(seed: int, q: int, p: int, m: int, S: int, n: int, scale: float = 1.0):
    rng = np.random.default_rng(seed)
    bank = SimpleNamespace(Gz=rng.standard_normal((q, m, S + 1)) * scale,
                           Gu=rng.standard_normal((p, m, S + 1)) * scale,
                           sigma=rng.uniform(0.5, 2.0, m), S=S, m=m)
    hyps = [Hypothesis("actuator", j, f"u{j}") for j in range(p)]
    hyps += [Hypothesis("actuator_bias", j, f"u{j}") for j in range(p)]
    hyps += [Hypothesis("sensor", j, f"y{j}") for j in range(q)]
    if q > 1:
        members = tuple(sorted(rng.choice(q, size=min(q, 3), replace=False).tolist()))
        hyps.append(Hypothesis("sensors", members[0], "joint", members=members))
    d = max(h.n_params for h in hyps)
    k = 1000 + np.arange(n)
    onsets = np.sort(rng.integers(990 - S, 1000 + n + 3, size=int(rng.integers(1, 20))))
    U = rng.standard_normal((n, S + 1, p))
    U[rng.random(U.shape) < 0.05] = np.nan
    rn = rng.standard_normal((n, m))
    rn[rng.random(rn.shape) < 0.1] = np.nan
    A = rng.standard_normal((m, m))
    gamma = A @ A.T / m + np.eye(m)
    return bank, hyps, regressor_columns(hyps, d), d, onsets, k, U, rn, gamma


def _compare(got, want):
    assert got.n_eq == want.n_eq
    np.testing.assert_allclose(got.rr, want.rr, rtol=1e-12)
    for name in ("J", "h", "meat"):
        a, b = getattr(got, name), getattr(want, name)
        assert a.shape == b.shape, name
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * max(1.0, np.abs(b).max()),
                                   err_msg=name)


@pytest.mark.parametrize(("q", "p", "m", "S", "n"), [
    (1, 1, 1, 0, 1), (4, 1, 6, 9, 1), (4, 1, 6, 9, 37), (3, 2, 5, 4, 12), (6, 3, 9, 12, 5),
    (2, 4, 3, 1, 50)])
def test_the_c_sums_are_numpys(q, p, m, S, n):
    for seed in range(4):
        case = _case(seed * 31 + q + 7 * m, q, p, m, S, n)
        _compare(kernel.get("c").information_block(*case), information_increments(*case))


def test_infinite_commands_read_as_numpys_nan_to_num():
    bank, hyps, cols, d, onsets, k, U, rn, gamma = _case(5, 3, 2, 4, 6, 8, scale=1e-300)
    U[0, 0, 0], U[1, 2, 1], U[3, -1, 0] = np.inf, -np.inf, np.inf
    case = (bank, hyps, cols, d, onsets, k, U, rn, gamma)
    got, want = kernel.get("c").information_block(*case), information_increments(*case)
    assert np.all(np.isfinite(want.J)) and np.all(np.isfinite(got.J))
    _compare(got, want)


def test_no_sample_adds_nothing():
    bank, hyps, cols, d, onsets, k, U, rn, gamma = _case(1, 2, 1, 3, 4, 3)
    got = kernel.get("c").information_block(bank, hyps, cols, d, onsets, k[:0], U[:0], rn[:0],
                                            gamma)
    assert got.n_eq == 0 and got.rr == 0.0 and not got.J.any() and not got.meat.any()


@pytest.mark.parametrize("column", [(4, 0), (-1, 0), (1, 9), (2, 5), (3, -1)])
def test_a_column_outside_the_bank_is_refused(column):
    bank, hyps, cols, d, onsets, k, U, rn, gamma = _case(2, 3, 2, 4, 3, 2)
    cols = cols.copy()
    cols[0, 0] = column
    with pytest.raises(ValueError, match="info_block: status"):
        kernel.get("c").information_block(bank, hyps, cols, d, onsets, k, U, rn, gamma)


def test_buffers_of_the_wrong_size_are_refused():
    from canfdi import _ckernel

    bank, _hyps, cols, d, onsets, k, U, rn, gamma = _case(3, 2, 1, 3, 2, 4)
    H, K, n = len(cols), len(onsets), len(k)
    out = [np.zeros((H, K, d, d)), np.zeros((H, K, d)), np.zeros((H, K, d, d)), np.zeros(1),
           np.zeros(1, dtype=np.int64), np.zeros(info_work(3, d, 2, 1, H))]
    args = [2, 1, 3, 2, bank.Gz, bank.Gu, bank.sigma, H, d, cols, K, onsets, n, k, U, rn, gamma]
    _ckernel.info_block(*args, *out)  # the right sizes pass
    for i, bad in ((4, bank.Gz[:1]), (15, rn[:1]), (16, gamma[:1])):
        wrong = list(args)
        wrong[i] = np.ascontiguousarray(bad)
        with pytest.raises(ValueError, match="expected"):
            _ckernel.info_block(*wrong, *out)
    with pytest.raises(ValueError, match="work"):
        _ckernel.info_block(*args, *out[:5], np.zeros(1))
    with pytest.raises(ValueError, match="sizes"):
        _ckernel.info_block(2, 1, 3, 2, bank.Gz, bank.Gu, bank.sigma, H, d, cols, K, onsets, -1,
                            k, U, rn, gamma, *out)


@pytest.mark.parametrize(("shape", "d"), [((), 1), ((3,), 2), ((7, 16), 2), ((4, 5), 4),
                                          ((2, 3), 6)])
def test_the_c_solution_is_numpys(shape, d):
    """cfdi_info_solve against rls_solve (numpy's LAPACK solve and inv): well-conditioned
    information, as a diagnosis' is, to 1e-12; a cost that cancels to 1e-12 of rr."""
    from canfdi.core.identify import RlsState, rls_solve

    rng = np.random.default_rng(d * 100 + len(shape))
    A = rng.standard_normal((*shape, d, 3 * d))
    J = A @ np.swapaxes(A, -1, -2) + 0.1 * np.eye(d)
    state = RlsState(J=J, h=rng.standard_normal((*shape, d)) * 10,
                     rr=rng.uniform(100, 1000, shape), n=5, n_eq=40)
    got, want = kernel.get("c").information_solve(state), rls_solve(state)
    assert got.dof == want.dof
    np.testing.assert_allclose(got.theta, want.theta, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(got.P, want.P, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(got.cost, want.cost, rtol=0,
                               atol=1e-12 * float(np.max(state.rr)))
    assert np.shape(got.cost) == np.shape(want.cost) == shape


def test_a_singular_information_raises_as_numpy_does():
    from canfdi.core.identify import RlsState, rls_solve

    J = np.zeros((2, 3, 2, 2))
    J[...] = np.eye(2)
    J[1, 2] = [[1.0, 2.0], [2.0, 4.0]]  # rank one: no inverse
    state = RlsState(J=J, h=np.ones((2, 3, 2)), rr=np.ones((2, 3)))
    with pytest.raises(np.linalg.LinAlgError):
        rls_solve(state)
    with pytest.raises(np.linalg.LinAlgError):
        kernel.get("c").information_solve(state)
