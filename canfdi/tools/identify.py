"""The library behind `canfdi identify`: a drive's model, its unknown inputs and its noise,
learned from healthy logs, validated on data left out, and refused when the data cannot
support it.

`identify` reads the logs with the config's bus (any format canfdi.io reads; a damaged MCAP
around its damage), puts each on its sample grid and keeps the last ``holdout`` of each (or
the ``validate`` logs) out of the fit. Then, by the config:

* a method with models of its own (its registry entry's ``fit_models``: output_error's OE
  models of the output-error paper, canfdi.methods.output_error.fit), fitted on the fit part;
* otherwise a state-space model: a grey-box template (canfdi.core.greybox) when
  ``model.identify.template`` names one, else black-box (canfdi.core.sysid: the measured state
  with its unknown inputs, or a PBSID subspace fit).

The model is checked on the held-out data (one-step and simulation fits per output, the
one-step errors' whiteness and correlation with the inputs: canfdi.core.validation), its
stability and minimality; its noise is then learned exactly as `canfdi calibrate` does, over
all the data, which also refuses a log in which the identified monitor detects something (a
fault in the log, with where); and its design (what `canfdi design` prints) is summarised.

A `Refusal` (exit 1) says what the data lack and what to record instead.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from canfdi import methods
from canfdi.bus.dbc import BusMap, load_dbc
from canfdi.config import parse_config
from canfdi.core.design import design_bank
from canfdi.core.model import StateSpace
from canfdi.core.settings import ConfigError, IdentifySpec, MonitorConfig
from canfdi.core.sysid import IdentifiedModel, identify_state_space
from canfdi.core.unknown_inputs import Record as FitRecord
from canfdi.core.validation import (
    initial_state,
    input_correlation,
    kalman_gain,
    minimality,
    nrmse,
    persistence,
    predict,
    simulate,
    stability,
    whiteness,
    with_unknown_inputs,
)
from canfdi.io.damage import Damage
from canfdi.tools.calibrate import LogFault, Record, calibrate_records, read_records
from canfdi.tools.samples import sample_period

if TYPE_CHECKING:
    from canfdi.tools.configdoc import ConfigDocument

__all__ = [
    "HOLDOUT",
    "MIN_FIT",
    "MIN_SAMPLES",
    "Identification",
    "Refusal",
    "config_document",
    "first_faulty_log",
    "identify",
    "jsonable",
    "period_of",
]

MIN_SAMPLES = 3000
"""Fewer samples than this in all the logs (30 s at 100 Hz) cannot support a model and its
validation."""
HOLDOUT = 0.3
"""The part of each log (its end) kept out of the fit for validation."""
MIN_FIT = 50.0
"""A one-step fit (NRMSE %) below this on an output the drive moves is refused."""
PE_ORDER = 10
"""The commands must excite dynamics of this order: their stacked windows of this many
samples must span every direction (their covariance's smallest eigenvalue at least PE_RTOL of
its largest), and each input must change (by more than its resolution) in at least
PE_CHANGES samples: a command that takes one step and holds excites too little."""
PE_RTOL = 1e-9
PE_CHANGES = 10 * PE_ORDER
MOVES = 10.0
"""An output whose variance is below this many times its noise variance is not moved by the
drive (its fit is not judged)."""
BURN_IN = 50
"""Validation samples spent estimating the state before the fits are scored."""
WHITE_MAX = 0.3
"""An output the unknown inputs do not reach whose one-step errors correlate more than this
at some lag (1 to 25) is not described by the model (its dynamics, or a change in the log)."""


class Refusal(ValueError):
    """The data cannot support a model: what is missing, and what to record instead."""


@dataclass
class Identification:
    """What `identify` learned.

    config : the identified (and calibrated) config. document : its plain YAML document
    (what parse_config took). updates : dotted key -> value, the sections a writer replaces
    in the user's file (model, signals.unknown_inputs, noise.measurement, and the method's own
    section for output_error). header : provenance comment lines. report : JSON-able report.
    """

    config: MonitorConfig
    document: dict
    updates: dict[str, Any]
    header: list[str]
    report: dict[str, Any]
    identified: IdentifiedModel | None = None
    notes: list[str] = field(default_factory=list)


def period_of(config: MonitorConfig) -> float:
    """The sample period: the model's dt, the clock's period, or the DBC's cycle time of the
    clock's trigger message (else of the fastest mapped message)."""
    dt = sample_period(config)
    if dt:
        return dt
    if config.bus.dbc is not None:
        database, _ = load_dbc(config.bus.dbc, config.path)
        names = {ref.message if not isinstance(ref.message, int) else None
                 for ref in config.bus.map.values()}
        cycles = []
        for message in database.messages:
            trig = config.bus.clock.message
            if trig is not None and trig in (message.name, message.frame_id):
                if message.cycle_time:
                    return message.cycle_time / 1000.0
            if message.name in names and message.cycle_time:
                cycles.append(message.cycle_time)
        if cycles:
            return min(cycles) / 1000.0
    raise ConfigError("model.dt", "the sample period is not known: give model.dt (or "
                                  "bus.clock.period for a grid clock)")


def first_faulty_log(paths: Sequence[Path]) -> tuple[Path, list[dict]] | None:
    """The first of the canfdi MCAPs among ``paths`` whose metadata says faults were injected
    while it was recorded (a demo's, a sim's), with those faults; None when there is none (a
    model is learned from a healthy drive only)."""
    from canfdi.io.logs import truth_of

    for path in paths:
        truth = truth_of(path) if path.suffix.lower() == ".mcap" else None
        if truth:
            return path, truth
    return None


def config_document(identification: Identification, document: ConfigDocument, source: Path,
                    logs: Sequence[Path], output: Path | None, when: str) -> ConfigDocument:
    """The identified config to write to ``output``: ``document`` (the config as read from
    ``source``, whose `plain` form `identify` took) with the identified sections set in place
    (``identification.updates``; None deletes a key), its relative paths pointing at the same
    files from ``output``'s folder (``source``'s when printed), and a header saying where it
    came from (date ``when``, config, ``logs``) above the identification's provenance lines.
    Everything else keeps the user's comments, order and literals.

    Returns
    -------
    ``document``, edited.
    """
    for key, value in identification.updates.items():
        if value is None:
            document.delete(key)
        else:
            document.set(key, value)
    document.relocate_paths(source, output or source)
    document.header([f"canfdi identify, {when}: {source.name} + "
                     f"{', '.join(p.name for p in logs)} -> "
                     f"{(output or Path('stdout')).name}", *identification.header])
    return document


def jsonable(value: Any) -> Any:
    """What the JSON of an identification's report holds for a value JSON has no form of
    (``json.dumps(report, default=jsonable)``): a complex number (an eigenvalue) as [real,
    imaginary], an array as a list, anything else as its text."""
    if isinstance(value, complex):
        return [value.real, value.imag]
    if hasattr(value, "tolist"):
        return value.tolist()
    return str(value)


def _split(records: Sequence[Record], holdout: float) -> tuple[list[Record], list[Record]]:
    fit, val = [], []
    for rec in records:
        cut = round(len(rec.k) * (1 - holdout))
        fit.append(Record(rec.name, rec.k[:cut], rec.U[:cut], rec.Z[:cut]))
        val.append(Record(rec.name, rec.k[cut:], rec.U[cut:], rec.Z[cut:]))
    return fit, [v for v in val if len(v.k)]


def _check_data(records: Sequence[Record], config: MonitorConfig, dt: float,
                u_res: np.ndarray) -> None:
    total = sum(len(r.k) for r in records)
    if total < MIN_SAMPLES:
        raise Refusal(f"{total} samples ({total * dt:.1f} s) in the logs: too short to "
                      f"identify and validate a model; record at least {MIN_SAMPLES * dt:.0f} s "
                      "of the drive while it is commanded steps and a chirp")
    stds, ratio = persistence([r.U for r in records], PE_ORDER)
    flat = [n for n, s, res in zip(config.inputs, stds, u_res, strict=True)
            if s <= max(2 * res, 1e-12 * (1 + s))]
    if flat:
        raise Refusal(f"the input {', '.join(flat)} is constant in the logs (it does not "
                      "excite the drive): record while the drive is commanded steps and a chirp "
                      "(or a PRBS) on it")
    changes = [int(sum(np.sum(np.abs(np.diff(r.U[:, i])) > 2 * res + 1e-12 * (1 + abs(s)))
                       for r in records))
               for i, (s, res) in enumerate(zip(stds, u_res, strict=True))]
    few = [f"{n} ({c} changes)" for n, c in zip(config.inputs, changes, strict=True)
           if c < PE_CHANGES]
    if ratio < PE_RTOL or few:
        what = (f"{', '.join(few)} change too seldom" if few else
                f"their windows of {PE_ORDER} samples span too few directions ({ratio:.1e})")
        raise Refusal(f"the inputs are not persistently exciting of order {PE_ORDER}: {what}; "
                      "record with richer commands: steps of several sizes and a chirp (or "
                      "a PRBS)")


def _fit_records(records: Sequence[Record]) -> list[FitRecord]:
    return [FitRecord(r.U, r.Z) for r in records]


def _spec(config: MonitorConfig) -> IdentifySpec:
    """The config's model.identify; for a config with a model and none, the model learned
    again with as many unknown inputs as its F has."""
    if config.identify is not None:
        return config.identify
    return IdentifySpec(unknown_inputs=config.model.r if config.model is not None else 0)


def _state_space(records: Sequence[Record], config: MonitorConfig, dt: float,
                 floor: np.ndarray, progress) -> tuple[IdentifiedModel, list[str], dict]:
    """(identified model, unknown-input names, template report or {})."""
    spec = _spec(config)
    prior = config.design.measurement_std
    if spec.template is not None:
        from canfdi.tools.identify_template import fit_with_template

        return fit_with_template(records, config, dt, floor, progress)
    model = identify_state_space(
        _fit_records(records), dt, unknown_inputs=spec.unknown_inputs, order=spec.order,
        delay=spec.delay, prior_std=prior, floor_std=floor, input_names=config.inputs,
        output_names=config.outputs, progress=progress)
    if model.unknown_inputs == 0 and model.order > len(config.outputs) and spec.order is None:
        model = _structured_or(model, records, config, dt, spec.delay, progress)
    given = list(config.unknown_inputs)
    names = (given if len(given) == model.unknown_inputs
             else [f"w{i + 1}" for i in range(model.unknown_inputs)])
    return model, names, {}


def _structured_or(subspace: IdentifiedModel, records: Sequence[Record], config: MonitorConfig,
                   dt: float, delay: int, progress) -> IdentifiedModel:
    """Where the data hold more states than the outputs show and no unknown input: each
    output's transfer functions from the inputs it depends on (the output-error paper's fit: a path
    the
    data cannot tell from none is none), realised block by block, keep the zeros a subspace
    fit's dense basis loses (the decoupled residuals need them: the winding machine's T1 does
    not depend on u3). Taken when minimal and its simulation fits on the held-out part are
    the subspace fit's (within a point); else the subspace fit."""
    from canfdi.core.sysid import parity_noise, realise_paths
    from canfdi.methods.output_error.fit import FitOptions, fit_output_error

    progress("fitting each output's transfer functions (output error, the output-error paper)")
    fit, val = _split(records, HOLDOUT)
    k, U, Z = _stacked(fit)
    try:
        oe = fit_output_error(k, U, Z, config.inputs, config.outputs,
                              FitOptions(delay=delay))
    except (ValueError, np.linalg.LinAlgError):
        return subspace
    m = oe["model"]
    paths = [(pr.output, pr.input, pr.b, pr.f, pr.delay) for pr in m.pairs]
    if not paths:
        return subspace
    offsets = m.y0 - m.static_gains() @ m.u0
    structured, names = realise_paths(paths, len(config.inputs), len(config.outputs), offsets,
                                      subspace.noise_std, dt)
    exempt = [i for i, name in enumerate(names) if name == "1"]
    bad = minimality(structured, exempt)
    if bad["unobservable"] or bad["uncontrollable"]:
        return subspace
    try:
        judged = {key: _validate(mod, subspace.noise_std, val, config.outputs, config.inputs)
                  for key, mod in (("subspace", subspace.model), ("structured", structured))}
    except Refusal:
        return subspace
    fits = {key: [o["simulation_fit"] for o in v["outputs"]] for key, v in judged.items()}
    if any(b is None or (a is not None and b < a - 1.0)
           for a, b in zip(fits["subspace"], fits["structured"], strict=True)):
        return subspace
    try:
        noise = parity_noise(structured, _fit_records(records), min(max(structured.n, 2), 10),
                             subspace.noise_std)
    except ValueError:
        noise = subspace.noise_std
    return IdentifiedModel(
        model=structured, state_names=names, path="output-error paths, realised",
        order=structured.n - len(exempt), order_evidence=subspace.order_evidence,
        noise_std=np.maximum(noise, 1e-300), unknown_inputs=0,
        notes=[*subspace.notes, f"each output's transfer functions ({len(paths)} paths) "
               "realised block by block: the subspace fit's simulation fits, and the zeros "
               "of the paths the data do not show"],
        details={"paths": [f"{config.outputs[j]} <- {config.inputs[i]}: B {list(b)}, "
                           f"F {list(f)}, delay {d}" for j, i, b, f, d in paths],
                 "subspace_simulation_fits": fits["subspace"]})


def model_section(model: StateSpace, spec_raw: Any) -> dict[str, Any]:
    """The ``model:`` section of an identified model: discrete, dt, the matrices (10
    significant digits), the user's ``identify:`` kept so the model can be learned again."""
    def mat(M: np.ndarray) -> list:
        return [[float(f"{v:.10g}") for v in row] for row in np.asarray(M)]

    out: dict[str, Any] = {"time": "discrete", "dt": float(model.dt or 0.0),
                           "A": mat(model.A), "B": mat(model.B), "C": mat(model.C)}
    if np.any(model.D):
        out["D"] = mat(model.D)
    if model.r:
        out["F"] = mat(model.F)
    if spec_raw is not None:
        out["identify"] = spec_raw
    return out


def _validate(model: StateSpace, noise_std: np.ndarray, records: Sequence[Record],
              outputs: Sequence[str], inputs: Sequence[str]) -> dict[str, Any]:
    """The fits and the one-step errors' checks on the held-out records."""
    walk = with_unknown_inputs(model)
    K = kalman_gain(walk, noise_std**2, unknown_inputs=model.r)
    sims, preds, ys, us = [], [], [], []
    for rec in records:
        if len(rec.k) <= BURN_IN + 10:
            continue
        x0 = initial_state(walk, rec.U, rec.Z, BURN_IN)
        yp = predict(walk, K, rec.U, rec.Z, x0)
        ys_sim = simulate(model, rec.U, x0[:model.n])
        sims.append(ys_sim[BURN_IN:])
        preds.append(yp[BURN_IN:])
        ys.append(rec.Z[BURN_IN:])
        us.append(rec.U[BURN_IN:])
    if not ys:
        raise Refusal("too few samples left out of the fit to validate the model: record "
                      "longer logs (or give --validate LOG)")
    Y, S, P, U = (np.vstack(a) for a in (ys, sims, preds, us))
    E = Y - P
    moves = np.nanvar(Y, axis=0) > MOVES * noise_std**2
    white = whiteness(E)
    corr = input_correlation(E, U)
    out = {"samples": len(Y), "outputs": []}
    fit_1 = nrmse(Y, P)
    fit_s = nrmse(Y, S)
    for j, name in enumerate(outputs):
        out["outputs"].append({
            "output": name, "one_step_fit": _finite(fit_1[j]),
            "simulation_fit": _finite(fit_s[j]), "moves": bool(moves[j]),
            "whiteness": white[j],
            "input_correlation": {inputs[i]: c for i, c in enumerate(corr[j]["inputs"])},
            "band": corr[j]["band"]})
    return out


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _change_point(model: StateSpace, records: Sequence[Record], j: int, dt: float) -> str:
    """Where output j's one-step error changes level most, as words ('near sample k (t s
    into LOG)'): the error of the state taken from the outputs (least squares on C, no
    predictor adapting to the change), y_j(k+1) - C_j (A x(k) + B u(k)), and the largest
    excursion of its cumulative sum about the mean (the classic single change point). Empty
    when the outputs do not show the state."""
    C = model.C
    n = model.n
    # A constant state (the operating point: x_c(k+1) = x_c(k), nothing drives it) is 1.
    const = [i for i in range(n) if np.array_equal(model.A[i], np.eye(n)[i])
             and not np.any(model.B[i]) and not np.any(model.F[i])]
    free = [i for i in range(n) if i not in const]
    if np.linalg.matrix_rank(C[:, free]) < len(free):
        return ""
    Cp = np.linalg.pinv(C[:, free])
    best = (0.0, "", 0)
    for rec in records:
        X = np.ones((len(rec.Z), n))
        X[:, free] = (rec.Z - rec.U @ model.D.T - C[:, const].sum(axis=1)) @ Cp.T
        e = rec.Z[1:, j] - (X[:-1] @ model.A.T + rec.U[:-1] @ model.B.T) @ C[j]
        e = np.where(np.isnan(e), 0.0, e - np.nanmean(e))
        excursion = np.abs(np.cumsum(e))
        i = int(np.argmax(excursion)) if len(e) else 0
        if len(e) and excursion[i] > best[0]:
            best = (float(excursion[i]), str(rec.name), i + 1)
    _, name, i = best
    return f"near sample {i} ({i * dt:.2f} s into {Path(name).name})" if name else ""


def _judge(validation: dict, identified: IdentifiedModel | None, model: StateSpace,
           where: Callable[[int], str] = lambda j: "") -> None:
    poor = [f"{o['output']} {o['one_step_fit']:.1f} %" for o in validation["outputs"]
            if o["moves"] and (o["one_step_fit"] is None or o["one_step_fit"] < MIN_FIT)]
    if poor:
        raise Refusal(f"the model predicts poorly on the data left out of the fit (one-step "
                      f"fit below {MIN_FIT:.0f} %: {', '.join(poor)}): record a longer log "
                      "with richer commands, or set model.identify.order / delay")
    # The unknown inputs' outputs carry the load's changes in their one-step errors; the
    # others' errors are the noise, white, when the model describes them.
    hit = np.abs(model.C @ model.F) if model.r else np.zeros((model.q, 0))
    reached = hit.max(axis=1, initial=0.0) > 1e-9 * max(hit.max(initial=0.0), 1e-300)
    coloured = [j for j, (o, far) in enumerate(zip(validation["outputs"], reached,
                                                    strict=True))
                if o["moves"] and not far and o["whiteness"]["max"] > WHITE_MAX]
    if coloured:
        j = coloured[0]
        o = validation["outputs"][j]
        raise Refusal(f"the one-step errors of {o['output']} are correlated (max "
                      f"{o['whiteness']['max']:.2f} at lags 1-25), which the unknown inputs do "
                      f"not explain: the log holds a change (a fault?) {where(j)}, or the model "
                      "misses dynamics or an unmeasured input; record a fault-free log, or set "
                      "model.identify.order / delay / unknown_inputs")
    exempt = [i for i, name in enumerate(identified.state_names if identified else [])
              if name == "1"]
    _, unstable = stability(model, exempt)
    if unstable:
        raise Refusal(f"the identified model is unstable (eigenvalues of modulus "
                      f"{', '.join(f'{m:.4f}' for m in unstable)}): the data do not pin its "
                      "slow dynamics; record longer, or set model.identify.order")
    bad = minimality(model, exempt)
    if bad["unobservable"] or bad["uncontrollable"]:
        parts = [f"{kind} modes at {', '.join(f'{v:.4g}' for v in vals)}"
                 for kind, vals in bad.items() if vals]
        raise Refusal("the identified model is not minimal (" + "; ".join(parts) + "): a "
                      "lower model.identify.order describes these data")


def _design_summary(config: MonitorConfig) -> list[dict[str, Any]]:
    """What `canfdi design` says per fault: detectable, isolable, the window, best f/n."""
    design = design_bank(config.model, config.inputs, config.outputs, config.design)
    confused = design.confused_with()
    names = design.input_names + design.output_names
    responds = design.responds
    sigma = np.array([r.noise_std for r in design.actuators + design.sensors])
    out = []
    p = design.model.p
    for kind, j, det in design.detectability:
        col = j if kind == "actuator" else p + j
        with np.errstate(divide="ignore", invalid="ignore"):
            ratios = np.abs(design.gain[:, col]) / sigma
        ok = np.isfinite(ratios) & responds[:, col]
        window = design.actuator_window if kind == "actuator" else design.sensor_window
        out.append({"kind": kind, "name": names[col], "detectable": bool(det.detectable),
                    "strongly_detectable": bool(det.strongly_detectable),
                    "isolable": bool(det.detectable) and not confused[col],
                    "same_signature_as": [names[k] for k in confused[col]],
                    "window": window,
                    "fault_to_noise": float(ratios[ok].max()) if ok.any() else 0.0})
    return out


def identify(paths: Sequence[Path], config: MonitorConfig, doc: dict, *,
             validate: Sequence[Path] = (), holdout: float = HOLDOUT,
             fit_options: Any = None,
             progress: Callable[[str], None] = lambda _: None,
             damage: Damage | None = None) -> Identification:
    """Learn, validate and calibrate the config's model from healthy logs (module
    docstring). ``doc`` is the config's plain YAML document; ``fit_options`` the options of
    a method that fits models of its own (its ``fit_models``; None: its defaults).

    Raises
    ------
    Refusal : the data cannot support a model (exit 1; the message says what to record).
    ValueError, ConfigError : unreadable logs or a config identify cannot use (exit 2).
    """
    dt = period_of(config)
    records = read_records(paths, config, progress, damage, dt)
    if validate:
        fit, val = records, read_records(validate, config, progress, damage, dt)
    else:
        fit, val = _split(records, holdout)
    every = list(records) + (list(val) if validate else [])
    bus_map = BusMap.from_config(config)
    U_all = np.vstack([r.U for r in every])
    Z_all = np.vstack([r.Z for r in every])
    u_res, z_res = bus_map.resolution(U_all, Z_all)
    _check_data(every, config, dt, u_res)
    method = methods.get(config.method)
    if method.fit_models is not None:
        return _own_models(method, fit, every, config, doc, dt, fit_options, progress)
    identified, w_names, template_report = _state_space(fit, config, dt, z_res, progress)
    model = identified.model
    raw_spec = (doc.get("model") or {}).get("identify")
    document = dict(doc)
    document["model"] = model_section(model, raw_spec)
    signals = dict(document.get("signals") or {})
    if model.r:
        signals["unknown_inputs"] = list(w_names)
    else:
        signals.pop("unknown_inputs", None)
    document["signals"] = signals
    noise = dict(document.get("noise") or {})
    noise["measurement"] = [float(f"{v:.4g}") for v in identified.noise_std]
    noise.pop("process", None)
    document["noise"] = noise
    progress("validating on the data left out of the fit")
    validation = _validate(model, identified.noise_std, val, config.outputs, config.inputs)
    def where(j: int) -> str:
        # The model fitted on data that hold a change has absorbed it; one fitted on the
        # first third of each log (before a change in its later part) shows where it is.
        head = [Record(r.name, r.k[: len(r.k) // 3], r.U[: len(r.k) // 3],
                       r.Z[: len(r.k) // 3]) for r in fit]
        try:
            early, _, _ = _state_space(head, config, dt, z_res, lambda _: None)
        except (ValueError, ConfigError):
            return ""
        return _change_point(early.model, every, j, dt)

    _judge(validation, identified, model, where)
    progress("learning the noise as `canfdi calibrate` does")
    staged = parse_config(document, config.path)
    try:
        calibration = calibrate_records(every, staged, document, progress=progress,
                                        floor_std=z_res)
    except LogFault as exc:
        raise Refusal(f"{exc}: a log with a fault (or a drive the model does not describe) "
                      "cannot teach the healthy drive; record a fault-free log") from None
    final = calibration.config
    design = _design_summary(final)
    report = {
        "logs": [str(p) for p in paths], "validate": [str(p) for p in validate],
        "samples": {"fit": int(sum(len(r.k) for r in fit)),
                    "validation": int(sum(len(r.k) for r in val))},
        "dt": dt, "path": identified.path, "order": identified.order,
        "states": identified.state_names, "order_evidence": identified.order_evidence,
        "unknown_inputs": {"count": model.r, "names": list(w_names)},
        "eigenvalues": [complex(v) for v in np.linalg.eigvals(model.A)],
        "details": identified.details, "notes": identified.notes,
        "validation": validation, "design": design,
        "calibration": calibration.report(),
        "resolution": {name: float(v) for name, v in zip(config.outputs, z_res, strict=True)},
    }
    if template_report:
        report["template"] = template_report
    updates = {"model": calibration.document["model"],
               "signals.unknown_inputs": calibration.document["signals"].get("unknown_inputs"),
               "noise.measurement": calibration.document["noise"]["measurement"]}
    header = _header(report)
    return Identification(config=final, document=calibration.document, updates=updates,
                          header=header, report=report, identified=identified,
                          notes=identified.notes)


def _own_models(method: methods.Method, fit: Sequence[Record], every: Sequence[Record],
                config: MonitorConfig, doc: dict, dt: float, options: Any, progress
                ) -> Identification:
    """The models of a method that fits its own (``method.fit_models``), fitted on the fit
    part; its section and ``method:`` written into the config."""
    k, U, Z = _stacked(fit)
    section, report = method.fit_models(k, U, Z, config, options, progress)
    document = dict(doc)
    document["method"] = method.name
    document[method.section] = section
    final = parse_config(document, config.path, allow_unidentified=True)
    report = {"logs": [str(r.name) for r in every], **report, "dt": dt}
    return Identification(config=final, document=document,
                          updates={method.section: section, "method": method.name},
                          header=[], report=report)


def _stacked(records: Sequence[Record]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(k, U, Z) of records end to end on one grid, 500 lost samples between two."""
    ks, us, zs = [], [], []
    offset = 0
    for rec in records:
        ok = ~np.isnan(rec.Z).all(axis=1)
        ks.append(np.arange(len(rec.k))[ok] + offset)
        us.append(rec.U[ok])
        zs.append(rec.Z[ok])
        offset += len(rec.k) + 500
    return np.concatenate(ks), np.vstack(us), np.vstack(zs)


def _header(report: dict) -> list[str]:
    """The provenance lines on top of the written config (without their "#")."""
    logs = ", ".join(Path(p).name for p in report["logs"])
    held = ("the last " + str(round(HOLDOUT * 100)) + " % of each log" if not report["validate"]
            else ", ".join(Path(p).name for p in report["validate"]))
    lines = [f"Identified from {report['samples']['fit']} samples of {len(report['logs'])} "
             f"log(s) ({logs}), validated on {report['samples']['validation']} samples left "
             f"out ({held}).",
             f"Model: {report['path']}, {report['order']} states ({', '.join(report['states'])}),"
             f" {report['unknown_inputs']['count']} unknown input(s), dt {report['dt']:g} s."]
    for o in report["validation"]["outputs"]:
        lines.append(f"  {o['output']}: one-step fit {_pct(o['one_step_fit'])}, simulation fit "
                     f"{_pct(o['simulation_fit'])}"
                     + ("" if o["moves"] else " (not moved by the drive)"))
    detectable = [d["name"] for d in report["design"] if d["detectable"]]
    undetectable = [d["name"] for d in report["design"] if not d["detectable"]]
    lines.append("Design: detectable " + (", ".join(detectable) or "none")
                 + ("; not detectable: " + ", ".join(undetectable) if undetectable else "")
                 + ".")
    lines.append("noise.measurement learned as `canfdi calibrate` does, over all the data.")
    return lines


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{x:.1f} %"
