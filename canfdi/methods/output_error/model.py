"""Output-error (OE) models of the output-error paper: parallel transfer functions B(q)/F(q) q^-d
per
input-output pair, their simulation, and their identification from fault-free data.

The output-error paper's (Section 2) models each output as a sum of parallel models, one per input,

    y_j(k) = sum_i w_ji(k) + e_j(k),   w_ji(k) = B_ji(q) / F_ji(q) q^-d_ji u_i(k),

with B(q) = b_0 + b_1 q^-1 + ... + b_{nb-1} q^-(nb-1) and F(q) = 1 + f_1 q^-1 + ... +
f_nf q^-nf. The models are *simulation* (parallel) models: they are driven by the measured
commands u_c only, never by past measurements, so the output-error residual r = z - y_hat sees
every additive fault (eqs. 9-11): a sensor fault directly, an actuator fault through G_ji.

Around an operating point (u0, y0) the model is y_hat_j = y0_j + sum_i G_ji (u_i - u0_i).

Identification (Ljung 1999, Section 7.3, the OE prediction-error method): the parameters
minimise the sum of squared simulation errors sum_k (y_j(k) - y_hat_j(k))^2, a nonlinear
least-squares problem, solved per output by Levenberg-Marquardt (scipy.optimize.least_squares)
with the analytic Jacobian

    d w / d b_l = q^-(d+l) u / F,     d w / d f_l = -q^-l w / F,

started from Steiglitz-McBride iterations (each pair fitted in turn to what the other pairs
leave, "backfitting"), which converge to the OE optimum for white output noise and give LM a
start in the right basin. The parameter covariance is sigma^2 (J^T J)^-1 at the optimum.
Why not Steiglitz-McBride alone: with several inputs of different denominators it does not
reach the joint optimum; why not ARX: its estimates are biased by output noise (the equation
error is coloured by F).

The same machinery fits the *residual's* response to a step (the output-error paper's Section 3.2):
`fit_step`.

Arrays: U (N, p) inputs, y (N,) one output; NaN is not allowed here (the diagnoser holds a
lost command, and masks lost measurements with ``valid``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from canfdi.core.identify import least_squares

__all__ = ["MisoFit", "OeModel", "OePair", "StepFit", "fit_miso", "fit_step", "long_run_ratio",
           "pair_initial_state", "simulate"]


# scipy.signal (and scipy.optimize) take ~0.7 s to import, pulling in scipy.stats: imported on
# first use, so that a monitor of another method, and `canfdi --help`, never pay for them.
def lfilter(b: np.ndarray, a: np.ndarray, x: np.ndarray, zi: np.ndarray | None = None):
    """scipy.signal.lfilter (y, or (y, zf) with ``zi``)."""
    from scipy.signal import lfilter as scipy_lfilter

    return scipy_lfilter(b, a, x, zi=zi)


def lfilter_zi(b: np.ndarray, a: np.ndarray) -> np.ndarray:
    """scipy.signal.lfilter_zi."""
    from scipy.signal import lfilter_zi as scipy_lfilter_zi

    return scipy_lfilter_zi(b, a)


@dataclass(frozen=True)
class OePair:
    """One path w = B(q)/F(q) q^-delay u_input into y_output.

    output, input : 0-based indices.
    b : (nb,) numerator b_0..b_{nb-1}; f : (nf,) denominator f_1..f_nf (monic F, the 1 implied).
    delay : d >= 0 samples.
    gain_std : the standard deviation of its static gain as its identification left it (0:
        known exactly): a fault's size seen through the path is uncertain by as much,
        relatively.

    Examples
    --------
    >>> pair = OePair(output=0, input=0, b=(0.1,), f=(-0.9,))
    >>> round(pair.static_gain, 12), pair.pole_radius, pair.state_size
    (1.0, 0.9, 1)
    >>> np.round(pair.step_response(4), 3)  # one sample of delay, then towards the gain of 1
    array([0.   , 0.1  , 0.19 , 0.271])
    """

    output: int
    input: int
    b: tuple[float, ...]
    f: tuple[float, ...]
    delay: int = 1
    gain_std: float = 0.0

    @property
    def num(self) -> np.ndarray:
        """(d + nb,) lfilter numerator: the delay as leading zeros."""
        return np.concatenate([np.zeros(self.delay), np.asarray(self.b, dtype=float)])

    @property
    def den(self) -> np.ndarray:
        """(1 + nf,) lfilter denominator [1, f_1, ..., f_nf]."""
        return np.concatenate([[1.0], np.asarray(self.f, dtype=float)])

    @property
    def static_gain(self) -> float:
        """B(1) / F(1)."""
        return float(np.sum(self.b) / (1.0 + np.sum(self.f)))

    @property
    def pole_radius(self) -> float:
        """Largest pole modulus of F (0 for a FIR path)."""
        return float(np.max(np.abs(np.roots(self.den)))) if self.f else 0.0

    @property
    def state_size(self) -> int:
        return max(len(self.num), len(self.den)) - 1

    def step_response(self, n: int) -> np.ndarray:
        """(n,) response to a unit step applied at sample 0."""
        return lfilter(self.num, self.den, np.ones(n))


@dataclass(frozen=True)
class OeModel:
    """Parallel OE models of a plant with p inputs and q outputs.

    pairs : the paths (an (output, input) not listed has no path).
    u0 : (p,) and y0 : (q,) the operating point: y_hat = y0 + sum G (u - u0).

    Examples
    --------
    >>> model = OeModel((OePair(0, 0, (0.1,), (-0.9,)), OePair(1, 0, (2.0,), ())),
    ...                 u0=[0.0], y0=[0.0, 5.0])
    >>> (model.q, model.p), model.static_gains().ravel(), model.has_path().ravel()
    ((2, 1), array([1., 2.]), array([ True,  True]))
    """

    pairs: tuple[OePair, ...]
    u0: np.ndarray
    y0: np.ndarray

    def __post_init__(self) -> None:
        u0 = np.asarray(self.u0, dtype=float).ravel()
        y0 = np.asarray(self.y0, dtype=float).ravel()
        object.__setattr__(self, "u0", u0)
        object.__setattr__(self, "y0", y0)
        seen = set()
        for pair in self.pairs:
            if not (0 <= pair.output < len(y0) and 0 <= pair.input < len(u0)):
                raise ValueError(f"pair y{pair.output}<-u{pair.input}: outside (q, p) = "
                                 f"({len(y0)}, {len(u0)})")
            if (pair.output, pair.input) in seen:
                raise ValueError(f"pair y{pair.output}<-u{pair.input} given twice")
            seen.add((pair.output, pair.input))

    @property
    def p(self) -> int:
        return len(self.u0)

    @property
    def q(self) -> int:
        return len(self.y0)

    def static_gains(self) -> np.ndarray:
        """(q, p) B(1)/F(1) per pair, 0 where there is no path."""
        K = np.zeros((self.q, self.p))
        for pair in self.pairs:
            K[pair.output, pair.input] = pair.static_gain
        return K

    def has_path(self) -> np.ndarray:
        """(q, p) bool."""
        out = np.zeros((self.q, self.p), dtype=bool)
        for pair in self.pairs:
            out[pair.output, pair.input] = True
        return out


def pair_initial_state(pair: OePair, u_dev: float) -> np.ndarray:
    """lfilter state of a pair at rest under the constant input deviation ``u_dev``."""
    if pair.state_size == 0:
        return np.zeros(0)
    return lfilter_zi(pair.num, pair.den) * u_dev


def simulate(model: OeModel, U_dev: np.ndarray, states: list[np.ndarray]
             ) -> tuple[np.ndarray, list[np.ndarray]]:
    """Model outputs for N samples of input deviations.

    Both the streaming path (N = 1) and the block path call this, so they share the
    arithmetic exactly (lfilter's direct form II transposed, sample by sample).

    Parameters
    ----------
    U_dev : (N, p) finite input deviations u - u0 (compensations included).
    states : one lfilter state per pair (``pair_initial_state``).

    Returns
    -------
    Y_hat : (N, q) model outputs y0 + sum_i w_ji; the new states.
    """
    n = U_dev.shape[0]
    Y = np.tile(model.y0, (n, 1))
    new = []
    for pair, zi in zip(model.pairs, states, strict=True):
        if pair.state_size == 0:
            w = pair.num[0] * U_dev[:, pair.input] if len(pair.num) else np.zeros(n)
            zf = zi
        else:
            w, zf = lfilter(pair.num, pair.den, U_dev[:, pair.input], zi=zi)
        Y[:, pair.output] += w
        new.append(zf)
    return Y, new


# ------------------------------------------------------------------------------------------
# identification
# ------------------------------------------------------------------------------------------


def _shift(x: np.ndarray, s: int) -> np.ndarray:
    """q^-s x with zeros shifted in."""
    if s == 0:
        return x
    out = np.zeros_like(x)
    if s < len(x):
        out[s:] = x[:-s]
    return out


@dataclass(frozen=True)
class _Structure:
    input: int
    nb: int
    nf: int
    delay: int


def _split(theta: np.ndarray, structure: list[_Structure]) -> list[tuple[np.ndarray, np.ndarray]]:
    out, at = [], 0
    for s in structure:
        b = theta[at: at + s.nb]
        f = theta[at + s.nb: at + s.nb + s.nf]
        out.append((b, f))
        at += s.nb + s.nf
    return out


def _stable(f: np.ndarray) -> bool:
    return len(f) == 0 or bool(np.all(np.abs(np.roots(np.concatenate([[1.0], f]))) < 1.0))


def _reflect(f: np.ndarray) -> np.ndarray:
    """F with its unstable roots reflected into the unit circle (Steiglitz-McBride safety)."""
    if len(f) == 0:
        return f
    roots = np.roots(np.concatenate([[1.0], f]))
    big = np.abs(roots) >= 0.995
    mod = np.abs(roots[big])
    roots[big] = roots[big] / mod * np.minimum(1.0 / mod, 0.99)
    return np.real(np.poly(roots))[1:]


def _simulate_terms(theta, structure, U, offset: bool):
    """(prediction (N,), per-pair outputs, per-pair inputs) for the parameter vector."""
    parts = _split(theta, structure)
    pred = np.full(U.shape[0], theta[-1] if offset else 0.0)
    ws = []
    for s, (b, f) in zip(structure, parts, strict=True):
        num = np.concatenate([np.zeros(s.delay), b])
        w = lfilter(num, np.concatenate([[1.0], f]), U[:, s.input])
        ws.append(w)
        pred = pred + w
    return pred, ws, parts


def _jacobian(theta, structure, U, offset: bool, ws, parts) -> np.ndarray:
    """(N, n_theta) d prediction / d theta."""
    cols = []
    for s, (_, f), w in zip(structure, parts, ws, strict=True):
        den = np.concatenate([[1.0], f])
        uf = lfilter([1.0], den, U[:, s.input])
        for lag in range(s.nb):
            cols.append(_shift(uf, s.delay + lag))
        if s.nf:
            wf = lfilter([1.0], den, w)
            for lag in range(1, s.nf + 1):
                cols.append(-_shift(wf, lag))
    if offset:
        cols.append(np.ones(U.shape[0]))
    return np.column_stack(cols)


def _steiglitz_mcbride(u: np.ndarray, t: np.ndarray, s: _Structure, weight: np.ndarray,
                       f0: np.ndarray | None = None, iterations: int = 12) -> np.ndarray:
    """(nb + nf,) SISO OE estimate of t = B/F q^-d u (+ a constant) by Steiglitz-McBride."""
    f = np.zeros(s.nf) if f0 is None else np.asarray(f0, dtype=float).copy()
    theta = np.zeros(s.nb + s.nf)
    for _ in range(iterations if s.nf else 1):
        den = np.concatenate([[1.0], f])
        uf, tf = lfilter([1.0], den, u), lfilter([1.0], den, t)
        cols = [_shift(uf, s.delay + lag) for lag in range(s.nb)]
        cols += [-_shift(tf, lag) for lag in range(1, s.nf + 1)]
        cols.append(np.ones_like(u))
        sol = least_squares(np.column_stack(cols), tf, weights=weight).theta
        theta = sol[: s.nb + s.nf]
        f_new = _reflect(theta[s.nb:])
        theta[s.nb:] = f_new
        if np.allclose(f_new, f, atol=1e-10):
            break
        f = f_new
    return theta


def _prediction_error_fit(U, y, structure, offset, weight, x0):
    """Levenberg-Marquardt on the simulation error; returns (theta, residual, J)."""
    big = 1e3 * (np.std(y) + 1.0)

    def fun(theta):
        if not all(_stable(f) for _, f in _split(theta, structure)):
            return np.full(len(y), big) * weight
        pred, _, _ = _simulate_terms(theta, structure, U, offset)
        return (y - pred) * weight

    def jac(theta):
        _, ws, parts = _simulate_terms(theta, structure, U, offset)
        return -_jacobian(theta, structure, U, offset, ws, parts) * weight[:, None]

    if len(x0) == 0:
        return x0, y * weight, np.zeros((len(y), 0))
    method = "lm" if int(weight.astype(bool).sum()) > len(x0) else "trf"
    try:
        from scipy import optimize

        sol = optimize.least_squares(fun, x0, jac=jac, method=method, xtol=1e-12, ftol=1e-12,
                                     gtol=1e-12, max_nfev=200)
        theta = sol.x
    except (ValueError, np.linalg.LinAlgError):
        theta = x0
    if not all(_stable(f) for _, f in _split(theta, structure)):
        theta = x0
    return theta, fun(theta), jac(theta)


@dataclass(frozen=True)
class MisoFit:
    """An OE fit of one output.

    pairs : the fitted OePair of each input in the structure (output index set by the caller).
    offset : the fitted constant (y - mean(y) = sum G (u - u0) + offset).
    cov : (n_theta, n_theta) parameter covariance (b, f of each pair in order, then offset).
    residual : (N,) simulation errors over the whole record (the warm-up included).
    sigma : residual standard deviation after the warm-up.
    gain_std : (n_pairs,) standard deviations of the static gains (delta method).

    Examples
    --------
    >>> from scipy.signal import lfilter
    >>> rng = np.random.default_rng(1)
    >>> U = np.sign(rng.standard_normal((2000, 1)))
    >>> y = lfilter([0.0, 0.2], [1.0, -0.8], U[:, 0]) + 0.01 * rng.standard_normal(2000)
    >>> fit = fit_miso(U, y - y.mean(), [(0, 1, 1, 1)], skip=50)
    >>> (pair,) = fit.pairs
    >>> np.round(pair.b, 2), np.round(pair.f, 2), round(fit.sigma, 3)
    (array([0.2]), array([-0.8]), 0.01)
    """

    pairs: tuple[OePair, ...]
    offset: float
    cov: np.ndarray
    residual: np.ndarray
    sigma: float
    gain_std: np.ndarray


def fit_miso(U_dev: np.ndarray, y_dev: np.ndarray, structure: list[tuple[int, int, int, int]],
             output: int = 0, skip: int = 200, rounds: int = 3,
             valid: np.ndarray | None = None) -> MisoFit:
    """Fit y_dev = sum_i B_i/F_i q^-d_i u_i + c (output error) by Steiglitz-McBride backfitting,
    then Levenberg-Marquardt on all parameters at once.

    Parameters
    ----------
    U_dev : (N, p) input deviations (u - u0); y_dev : (N,) output deviations (y - mean y).
    structure : (input, nb, nf, delay) per path of this output.
    output : the output index written into the returned pairs.
    skip : the first samples left out of the cost (the models start at rest, the plant not).
    rounds : backfitting rounds before the joint fit.
    valid : (N,) False where y_dev is unknown (a lost measurement): no equation there.
    """
    U_dev = np.asarray(U_dev, dtype=float)
    y_dev = np.asarray(y_dev, dtype=float)
    if U_dev.ndim != 2 or y_dev.shape != (U_dev.shape[0],):
        raise ValueError(f"U_dev (N, p) and y_dev (N,): got {U_dev.shape} and {y_dev.shape}")
    st = [_Structure(*s) for s in structure]
    n = len(y_dev)
    weight = np.ones(n)
    weight[: min(skip, n // 4)] = 0.0
    if valid is not None:
        weight[~np.asarray(valid, dtype=bool)] = 0.0
        y_dev = np.where(weight > 0, y_dev, 0.0)
    thetas = [np.zeros(s.nb + s.nf) for s in st]
    for _ in range(rounds):
        for idx, s in enumerate(st):
            others = np.zeros(n)
            for jdx, (s2, th) in enumerate(zip(st, thetas, strict=True)):
                if jdx != idx:
                    others += lfilter(np.concatenate([np.zeros(s2.delay), th[: s2.nb]]),
                                      np.concatenate([[1.0], th[s2.nb:]]), U_dev[:, s2.input])
            thetas[idx] = _steiglitz_mcbride(U_dev[:, s.input], y_dev - others, s, weight,
                                             f0=thetas[idx][s.nb:] if _ else None)
    x0 = np.concatenate([*thetas, np.zeros(1)])
    theta, res_w, J = _prediction_error_fit(U_dev, y_dev, st, True, weight, x0)
    used = int(weight.sum())
    dof = max(used - len(theta), 1)
    sigma2 = float(res_w @ res_w) / dof
    cov = sigma2 * np.linalg.pinv(J.T @ J)
    pred, _, parts = _simulate_terms(theta, st, U_dev, True)
    pairs, gain_std, at = [], [], 0
    for s, (b, f) in zip(st, parts, strict=True):
        # Static gain K = sum b / (1 + sum f): gradient 1/F(1) on b, -K/F(1) on f.
        f1 = 1.0 + float(np.sum(f))
        grad = np.zeros(len(theta))
        grad[at: at + s.nb] = 1.0 / f1
        grad[at + s.nb: at + s.nb + s.nf] = -float(np.sum(b)) / f1**2
        gain_std.append(float(np.sqrt(max(grad @ cov @ grad, 0.0))))
        pairs.append(OePair(output=output, input=s.input, b=tuple(map(float, b)),
                            f=tuple(map(float, f)), delay=s.delay, gain_std=gain_std[-1]))
        at += s.nb + s.nf
    residual = y_dev - pred
    return MisoFit(pairs=tuple(pairs), offset=float(theta[-1]), cov=cov, residual=residual,
                   sigma=float(np.std(residual[weight > 0])), gain_std=np.array(gain_std))


def long_run_ratio(r: np.ndarray, block: int = 50) -> float:
    """Long-run variance of a residual over its variance (1 for white noise), by batch means.

    A Page-Hinkley threshold for white noise is too low for a correlated residual (model error
    colours the OE residual); this ratio scales it (see canfdi.methods.output_error.diagnoser)."""
    r = np.asarray(r, dtype=float)
    r = r[~np.isnan(r)]
    n_blocks = len(r) // block
    if n_blocks < 10 or np.var(r) == 0:
        return 1.0
    means = r[: n_blocks * block].reshape(n_blocks, block).mean(axis=1)
    return float(means.var(ddof=1) * block / np.var(r))


@dataclass(frozen=True)
class StepFit:
    """The residual's response to a step, fitted as an OE model B/F q^-d of a given structure.

    b, f : estimates; var_b, var_f : their variances (sigma^2 (J^T J)^-1, sigma^2 estimated
    from the fit); cost : sum of squared errors; n : equations used; held_costs : for each of
    the fit's ``f_starts``, the cost with F held there and B fitted (a known shape, its gain
    free: never below ``cost``).

    Examples
    --------
    >>> from scipy.signal import lfilter
    >>> r = lfilter([0.0, 0.3], [1.0, -0.7], (np.arange(200) >= 50).astype(float))
    >>> fit = fit_step(r, onset=50, nb=1, nf=1, delay=1)
    >>> np.round(fit.b, 3), np.round(fit.f, 3), fit.n
    (array([0.3]), array([-0.7]), 200)
    """

    b: np.ndarray
    f: np.ndarray
    var_b: np.ndarray
    var_f: np.ndarray
    cost: float
    n: int
    held_costs: tuple[float, ...] = ()

    @property
    def static_gain(self) -> float:
        return float(np.sum(self.b) / (1.0 + np.sum(self.f)))


def fit_step(r: np.ndarray, onset: int, nb: int, nf: int, delay: int,
             valid: np.ndarray | None = None, f_starts: tuple[np.ndarray, ...] = ()) -> StepFit:
    """Fit r(k) = B(q)/F(q) q^-delay U(k - onset) (the output-error paper's eq. 12, the amplitude
    in B).

    Parameters
    ----------
    r : (N,) residual; NaN or ``valid`` False rows give no equation.
    onset : row of r where the unit step starts (may be <= 0 or >= N).
    nb, nf, delay : the structure of the hypothesis' model.
    f_starts : denominators (nf,) to start Levenberg-Marquardt from, besides F = 1 (pure gain);
        the best optimum is kept (the cost of a step fit can have several minima).
    """
    r = np.asarray(r, dtype=float)
    ok = ~np.isnan(r) if valid is None else (np.asarray(valid, dtype=bool) & ~np.isnan(r))
    y = np.where(ok, r, 0.0)
    weight = ok.astype(float)
    u = np.zeros((len(r), 1))
    u[max(onset, 0):, 0] = 1.0
    st = [_Structure(0, nb, nf, delay)]
    best = None
    starts = [np.zeros(nf)] + [np.asarray(f, dtype=float) for f in f_starts]
    held = []
    for f0 in starts:
        # B given F is linear: start from its least-squares value.
        uf = lfilter([1.0], np.concatenate([[1.0], f0]), u[:, 0])
        X = np.column_stack([_shift(uf, delay + lag) for lag in range(nb)])
        if nb:
            gain = least_squares(X, y, weights=weight)
            b0, held_cost = gain.theta, float(gain.cost)
        else:
            b0, held_cost = np.zeros(0), float(np.sum(weight * y**2))
        held.append(held_cost)
        theta, res_w, J = _prediction_error_fit(u, y, st, False, weight,
                                                 np.concatenate([b0, f0]))
        cost = float(res_w @ res_w)
        if best is None or cost < best[0]:
            best = (cost, theta, J)
    cost, theta, J = best
    n = int(weight.sum())
    sigma2 = cost / max(n - len(theta), 1)
    var = sigma2 * np.diag(np.linalg.pinv(J.T @ J))
    return StepFit(b=theta[:nb], f=theta[nb:], var_b=var[:nb], var_f=var[nb:], cost=cost, n=n,
                   held_costs=tuple(held[1:]))
