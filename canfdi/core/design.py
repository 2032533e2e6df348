"""The residual bank of a model: windows, vectors, detectability, isolability, noise gaps.

This is what `canfdi design` reports and what the diagnoser runs: one fully decoupled residual
per actuator (sees that actuator only) and one per sensor (blind to that sensor, sees the others),
all actuator residuals at one window order and all sensor residuals at another, so each bank is
one matrix V whose rows are the parity vectors.

Gains are responses to a unit constant fault: for actuator fault j in residual v,
sum(v^T Hc[:, cols_j]) (a bias of 1 on u_j); for sensor fault j, (v^T I*)_j (a bias of 1 on y_j).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from canfdi.core.detectability import Detectability, model_detectability
from canfdi.core.model import StateSpace
from canfdi.core.parity import (
    ParityVector,
    actuator_columns,
    design_actuator,
    design_sensor,
    identity_stack,
    parity_matrices,
    sensor_rows,
    smallest_window,
    window_noise_covariance,
)

__all__ = ["Design", "DesignOptions", "ResidualDesign", "design_bank", "design_to_dict"]

#: Gains below this fraction of the table's largest gain count as "does not respond".
RESPONSE_RTOL = 1e-9
#: A sensor bias is jointly estimable when its regressor column keeps this fraction of its norm
#: after projecting out the other sensors' columns.
IDENTIFIABLE_RTOL = 1e-6


@dataclass(frozen=True)
class DesignOptions:
    """Design choices (the config's ``design:`` and ``noise:`` sections).

    actuator_window, sensor_window : fixed window orders, or None for the smallest admissible.
    max_window : largest s searched when the window is not fixed.
    measurement_std : (q,) sensor noise standard deviations (ones when None: gaps are relative).
    process_std : (n,) process noise standard deviations (zeros when None).
    compare_windows : how many window orders above the chosen one the comparison table shows.

    Examples
    --------
    >>> options = DesignOptions(max_window=6, measurement_std=np.array([0.01, 0.02]))
    >>> options.max_window, options.actuator_window, options.compare_windows
    (6, None, 4)
    """

    actuator_window: int | None = None
    sensor_window: int | None = None
    max_window: int = 10
    measurement_std: np.ndarray | None = None
    process_std: np.ndarray | None = None
    compare_windows: int = 4


@dataclass(frozen=True)
class ResidualDesign:
    """One residual of the bank, with its noise figures.

    Attributes
    ----------
    min_window : smallest admissible s for this fault alone, or None when none up to max_window.
    noise_std : sqrt(v^T Sigma v), the residual's noise standard deviation (nan without vector).
    bias_gain : response to a unit constant fault on its own actuator (actuator residuals), or
        the norm of its sensor gains (sensor residuals).
    fault_to_noise : abs(bias_gain) / noise_std.

    Examples
    --------
    >>> from canfdi.core.model import StateSpace
    >>> model = StateSpace(A=[[0.9]], B=[[1.0]], C=[[1.0], [1.0]], dt=0.01)
    >>> residual = design_bank(model, ["u"], ["y0", "y1"]).sensors[0]
    >>> residual.name, residual.vector.exists, residual.min_window
    ('s:y0', True, 1)
    """

    name: str
    vector: ParityVector
    min_window: int | None
    noise_std: float
    bias_gain: float
    fault_to_noise: float


@dataclass(frozen=True)
class Design:
    """The designed bank of a model.

    Attributes
    ----------
    model : the discrete model the bank runs on (ZOH of the source model if it was continuous).
    source : the model as configured.
    input_names, output_names : names of u and y entries.
    actuators, sensors : one ResidualDesign per actuator / sensor.
    actuator_window, sensor_window : the bank's window orders (None when no vector exists).
    detectability : per fault (kind, index, Detectability) in the source model's time domain.
    detectability_discrete : the same for the discrete model when the source is continuous.
    gain : (n_residuals, p + q) response of each residual to each unit constant fault.
    response : (n_residuals, p + q) norm of the residual's response to any fault sequence
        (||v^T Hc[:, cols_j]|| for actuator j, ||v on sensor j's rows|| for sensor j): nonzero
        exactly when the residual responds to the fault at all, constant or not.
    window_comparison : per fault, sensitivity and fault-to-noise at several window orders.

    Examples
    --------
    >>> from canfdi.core.model import StateSpace
    >>> model = StateSpace(A=[[0.9]], B=[[1.0]], C=[[1.0], [1.0]], dt=0.01)
    >>> design = design_bank(model, ["u"], ["y0", "y1"])
    >>> design.residual_names, design.sensor_window
    (['a:u', 's:y0', 's:y1'], 1)
    >>> design.responds
    array([[ True,  True,  True],
           [ True, False,  True],
           [ True,  True, False]])
    """

    model: StateSpace
    source: StateSpace
    input_names: list[str]
    output_names: list[str]
    actuators: list[ResidualDesign]
    sensors: list[ResidualDesign]
    actuator_window: int | None
    sensor_window: int | None
    detectability: list[tuple[str, int, Detectability]]
    detectability_discrete: list[tuple[str, int, Detectability]] | None
    gain: np.ndarray
    response: np.ndarray
    window_comparison: list[dict] = field(default_factory=list)

    @property
    def residual_names(self) -> list[str]:
        return [r.name for r in self.actuators] + [r.name for r in self.sensors]

    @property
    def fault_names(self) -> list[str]:
        return self.input_names + self.output_names

    @property
    def responds(self) -> np.ndarray:
        """(n_residuals, p + q) bool: which residual responds to which fault."""
        scale = np.max(self.response) if self.response.size else 0.0
        return self.response > RESPONSE_RTOL * max(scale, 1e-300)

    def sensor_matrix(self) -> np.ndarray:
        """V of the sensor bank: (q_exist, (s+1) q) rows of the existing sensor residuals."""
        rows = [r.vector.vector for r in self.sensors if r.vector.exists]
        width = 0 if self.sensor_window is None else (self.sensor_window + 1) * self.model.q
        return np.array(rows) if rows else np.zeros((0, width))

    def sensor_jointly_estimable(self) -> np.ndarray:
        """(q,) bool: bias of sensor j can be estimated together with all others (eq. 41).

        Column j of Phi = V I* must keep a part outside the span of the other columns;
        otherwise only a combination of biases reaches the residuals. (Under a single-fault
        assumption a detectable bias is estimable whenever its column is nonzero.)
        """
        V = self.sensor_matrix()
        q = self.model.q
        out = np.zeros(q, dtype=bool)
        if V.shape[0] == 0:
            return out
        Phi = V @ identity_stack(q, self.sensor_window)
        for j in range(q):
            col = Phi[:, j]
            norm = np.linalg.norm(col)
            if norm <= RESPONSE_RTOL * max(np.max(np.abs(Phi)), 1e-300):
                continue
            others = np.delete(Phi, j, axis=1)
            if others.shape[1]:
                coef, *_ = np.linalg.lstsq(others, col, rcond=None)
                rest = col - others @ coef
            else:
                rest = col
            out[j] = np.linalg.norm(rest) > IDENTIFIABLE_RTOL * norm
        return out

    def confused_with(self) -> list[list[int]]:
        """For each fault (actuators then sensors) the other faults with the same signature."""
        R = self.responds
        n = R.shape[1]
        out = []
        for j in range(n):
            if not R[:, j].any():
                out.append([])
                continue
            out.append([k for k in range(n) if k != j and np.array_equal(R[:, j], R[:, k])])
        return out


def _noise_std(v: np.ndarray, Sigma: np.ndarray) -> float:
    return float(np.sqrt(max(v @ Sigma @ v, 0.0)))


def _bank(model: StateSpace, designer, count: int, fixed: int | None, max_window: int
          ) -> tuple[int | None, list[ParityVector], list[int | None]]:
    minimal = [smallest_window(designer, model, i, max_window) for i in range(count)]
    min_windows = [d.s if d.exists else None for d in minimal]
    if fixed is not None:
        window = fixed
    else:
        found = [s for s in min_windows if s is not None]
        window = max(found) if found else None
    if window is None:
        return None, minimal, min_windows
    return window, [designer(model, i, window) for i in range(count)], min_windows


def _unseen(model: StateSpace, vectors: list[ParityVector], wanted: list[int]) -> list[int]:
    """The faults (columns of [actuators, sensors]) in ``wanted`` no residual responds to."""
    rows = [_unit_fault_gains(model, pv.vector, pv.s)[1] for pv in vectors if pv.exists]
    if not rows:
        return list(wanted)
    response = np.array(rows)
    seen = (response > RESPONSE_RTOL * max(response.max(), 1e-300)).any(axis=0)
    return [c for c in wanted if not seen[c]]


def _seeing_every_fault(model: StateSpace, detectability: list, options: DesignOptions,
                        actuator: tuple, sensor: tuple) -> tuple:
    """The banks at the smallest windows, or, when a fault the model can detect leaves every
    residual there untouched, at the smallest larger windows where each such fault moves
    some residual (the sensor bank grown first; a fixed window stays). Parity vectors at
    the smallest window can all miss a fault that a longer window sees: an identified servo
    axis whose velocity bias only shows through a second sample of the setpoint's echo.

    ``detectability``: `model_detectability` of the source model. ``actuator``, ``sensor``:
    (designer, window, vectors). Returns (actuator window, vectors,
    sensor window, vectors)."""
    (act, a_window, a_vectors), (sen, s_window, s_vectors) = actuator, sensor
    wanted = [j if kind == "actuator" else model.p + j
              for kind, j, d in detectability if d.detectable]
    before = _unseen(model, a_vectors + s_vectors, wanted)
    if not before or a_window is None or s_window is None:
        return a_window, a_vectors, s_window, s_vectors
    grow_a = options.actuator_window is None
    grow_s = options.sensor_window is None
    top = options.max_window
    for extra in range(1, 2 * top + 1):
        for ds in range(extra, -1, -1):
            da = extra - ds
            if (da and not grow_a) or (ds and not grow_s):
                continue
            aw, sw = a_window + da, s_window + ds
            if aw > top or sw > top:
                continue
            av = a_vectors if not da else [act(model, i, aw) for i in range(model.p)]
            sv = s_vectors if not ds else [sen(model, i, sw) for i in range(model.q)]
            if not _unseen(model, av + sv, before):
                return aw, av, sw, sv
    return a_window, a_vectors, s_window, s_vectors


def _unit_fault_gains(model: StateSpace, v: np.ndarray, s: int) -> tuple[np.ndarray, np.ndarray]:
    """Responses of residual v (window s) to each actuator and sensor fault, shapes (p + q,).

    Returns (gain to a unit constant fault, norm of the response to an arbitrary fault).
    """
    Hc = parity_matrices(model, s).Hc
    act = [v @ Hc[:, actuator_columns(model.p, s, j)] for j in range(model.p)]
    sen = [v[sensor_rows(model.q, s, j)] for j in range(model.q)]
    gain = np.array([row.sum() for row in act + sen])
    response = np.array([np.linalg.norm(row) for row in act + sen])
    return gain, response


def design_bank(source: StateSpace, input_names: list[str], output_names: list[str],
                options: DesignOptions | None = None) -> Design:
    """Design the residual bank of a model and analyse it.

    Parameters
    ----------
    source : the configured model (continuous models are discretised with ZOH at dt).
    input_names : p names; output_names : q names.
    """
    options = options or DesignOptions()
    model = source.discretize()
    if len(input_names) != model.p:
        raise ValueError(f"input_names: expected {model.p} names, got {len(input_names)}")
    if len(output_names) != model.q:
        raise ValueError(f"output_names: expected {model.q} names, got {len(output_names)}")
    meas = (np.ones(model.q) if options.measurement_std is None
            else np.asarray(options.measurement_std, dtype=float))
    proc = (np.zeros(model.n) if options.process_std is None
            else np.asarray(options.process_std, dtype=float))

    # Sensors of different noise: each vector chosen per unit of its own noise (parity.py).
    weighted = options.measurement_std is not None

    def act(m, i, s):
        return design_actuator(m, i, s, meas if weighted else None)

    def sen(m, i, s):
        return design_sensor(m, i, s, meas if weighted else None)

    a_window, a_vectors, a_min = _bank(model, act, model.p, options.actuator_window,
                                       options.max_window)
    s_window, s_vectors, s_min = _bank(model, sen, model.q, options.sensor_window,
                                       options.max_window)
    detectability = model_detectability(source)
    a_window, a_vectors, s_window, s_vectors = _seeing_every_fault(
        model, detectability, options, (act, a_window, a_vectors), (sen, s_window, s_vectors))

    def finish(vectors, mins, names, window, kind):
        out, gains, responses = [], [], []
        Sigma = (window_noise_covariance(model, window, meas, proc)
                 if window is not None else None)
        for pv, mw, name in zip(vectors, mins, names, strict=True):
            if pv.exists:
                sd = _noise_std(pv.vector, Sigma)
                g, resp = _unit_fault_gains(model, pv.vector, pv.s)
                bias = g[pv.index] if kind == "actuator" else float(np.linalg.norm(pv.gain))
                gains.append(g)
                responses.append(resp)
            else:
                sd, bias = float("nan"), 0.0
                gains.append(np.zeros(model.p + model.q))
                responses.append(np.zeros(model.p + model.q))
            ftn = abs(bias) / sd if pv.exists and sd > 0 else (float("inf") if pv.exists else 0.0)
            out.append(ResidualDesign(name=f"{kind[0]}:{name}", vector=pv, min_window=mw,
                                      noise_std=sd, bias_gain=float(bias), fault_to_noise=ftn))
        return out, gains, responses

    actuators, a_gains, a_resp = finish(a_vectors, a_min, input_names, a_window, "actuator")
    sensors, s_gains, s_resp = finish(s_vectors, s_min, output_names, s_window, "sensor")
    size = model.p + model.q
    gain = np.array(a_gains + s_gains).reshape(size, size)
    # Round-off of exact zeros (a constant fault the residual cancels) is reported as zero.
    gain[np.abs(gain) <= RESPONSE_RTOL * max(np.max(np.abs(gain), initial=0.0), 1e-300)] = 0.0
    response = np.array(a_resp + s_resp).reshape(size, size)

    comparison = []
    for kind, designer, names, window in (
        ("actuator", act, input_names, a_window),
        ("sensor", sen, output_names, s_window),
    ):
        if window is None:
            continue
        for i, name in enumerate(names):
            rows = []
            for s in range(window, window + options.compare_windows + 1):
                pv = designer(model, i, s)
                if not pv.exists:
                    rows.append({"window": s, "exists": False})
                    continue
                sd = _noise_std(pv.vector, window_noise_covariance(model, s, meas, proc))
                g, _ = _unit_fault_gains(model, pv.vector, s)
                bias = g[i] if kind == "actuator" else float(np.linalg.norm(pv.gain))
                rows.append({"window": s, "exists": True, "sensitivity": pv.sensitivity,
                             "noise_std": sd, "fault_to_noise": abs(bias) / sd if sd else None})
            comparison.append({"kind": kind, "index": i, "name": name, "by_window": rows})

    return Design(
        model=model, source=source, input_names=list(input_names),
        output_names=list(output_names), actuators=actuators, sensors=sensors,
        actuator_window=a_window, sensor_window=s_window,
        detectability=detectability,
        detectability_discrete=model_detectability(model) if source.continuous else None,
        gain=gain, response=response, window_comparison=comparison,
    )


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def design_to_dict(design: Design) -> dict:
    """JSON-ready summary of a design (the `canfdi design --json` contract)."""
    def residual_entry(r: ResidualDesign) -> dict:
        pv = r.vector
        entry = {
            "index": pv.index, "name": r.name.split(":", 1)[1], "window": pv.s,
            "min_window": r.min_window, "exists": pv.exists,
            "vector": None if pv.vector is None else [float(x) for x in pv.vector],
            "sensitivity": float(pv.sensitivity),
            "gain": None if pv.gain is None else [float(x) for x in pv.gain],
            "noise_std": _finite(r.noise_std), "bias_gain": float(r.bias_gain),
            "fault_to_noise": _finite(r.fault_to_noise),
            "decoupling_residual": pv.decoupling_residual,
            "null_dim": pv.null_dim, "rank": pv.rank, "rows": pv.rows, "reason": pv.reason,
        }
        if pv.kind == "sensor" and pv.gain is not None:
            entry["sees"] = [design.output_names[j] for j in range(design.model.q)
                             if design.responds[design.model.p + pv.index, design.model.p + j]]
        return entry

    names = design.fault_names
    responds = design.responds
    confused = design.confused_with()
    jointly = design.sensor_jointly_estimable()
    p = design.model.p

    def detect_entry(kind: str, j: int, d: Detectability) -> dict:
        col = j if kind == "actuator" else p + j
        sig = np.array([r.noise_std for r in design.actuators + design.sensors])
        with np.errstate(divide="ignore", invalid="ignore"):
            ratios = np.abs(design.gain[:, col]) / sig
        ratios = ratios[np.isfinite(ratios) & responds[:, col]]
        entry = {
            "kind": kind, "index": j,
            "name": design.input_names[j] if kind == "actuator" else design.output_names[j],
            "detectable": d.detectable, "strongly_detectable": d.strongly_detectable,
            "response": d.response, "steady_response": d.steady_response,
            "reason": d.reason,
            "residuals": [design.residual_names[i] for i in np.flatnonzero(responds[:, col])],
            "confused_with": [names[k] for k in confused[col]],
            "isolable": bool(responds[:, col].any()) and not confused[col],
            "best_fault_to_noise": float(ratios.max()) if ratios.size else 0.0,
        }
        if kind == "sensor":
            entry["jointly_estimable"] = bool(jointly[j])
        return entry

    out = {
        "model": {
            "n": design.source.n, "p": design.source.p, "q": design.source.q,
            "r": design.source.r, "r1": design.source.r1,
            "time": "continuous" if design.source.continuous else "discrete",
            "dt": design.source.dt,
        },
        "windows": {"actuator": design.actuator_window, "sensor": design.sensor_window},
        "actuators": [residual_entry(r) for r in design.actuators],
        "sensors": [residual_entry(r) for r in design.sensors],
        "detectability": [detect_entry(k, j, d) for k, j, d in design.detectability],
        "isolability": {
            "residuals": design.residual_names, "faults": names,
            "gain": [[float(x) for x in row] for row in design.gain],
            "response": [[float(x) for x in row] for row in design.response],
            "responds": [[bool(x) for x in row] for row in responds],
        },
        "window_comparison": design.window_comparison,
    }
    if design.detectability_discrete is not None:
        out["detectability_discrete"] = [
            {"kind": k, "index": j, "detectable": d.detectable,
             "strongly_detectable": d.strongly_detectable, "reason": d.reason}
            for k, j, d in design.detectability_discrete
        ]
    return out
