"""The output_error method (the output-error paper): OE fit, streaming = block, decision tests,
config."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.signal import lfilter

from canfdi.config import ConfigError, load_config, read_yaml
from canfdi.core.records import Compensation
from canfdi.methods.output_error.diagnoser import OeSettings, OutputErrorDiagnoser, settling_samples
from canfdi.methods.output_error.model import OePair, fit_miso, fit_step

REPO = Path(__file__).resolve().parents[2]
CONFIG = REPO / "deploy" / "config" / "winding_machine_oe.yaml"


def _plant(n: int, noise: float, seed: int = 0):
    """Two inputs into one output: 0.45/(1-0.85q^-1) q^-1 u0 + (0.1+0.05q^-1)/((1-0.95q^-1)
    (1-0.7q^-1)) q^-1 u1, excited by held random steps; plus an offset 0.3."""
    rng = np.random.default_rng(seed)
    U = np.repeat(rng.standard_normal((n // 5 + 1, 2)), 5, axis=0)[:n]
    y = (lfilter([0, 0.45], [1, -0.85], U[:, 0])
         + lfilter([0, 0.10, 0.05], [1, -1.65, 0.665], U[:, 1]) + 0.3)
    return U, y + noise * rng.standard_normal(n)


def test_oe_fit_recovers_a_known_model_from_noise_free_data():
    U, y = _plant(3000, 0.0)
    fit = fit_miso(U, y - y.mean(), [(0, 1, 1, 1), (1, 2, 2, 1)], skip=0)
    a, b = fit.pairs
    np.testing.assert_allclose(a.b, [0.45], atol=1e-7)
    np.testing.assert_allclose(a.f, [-0.85], atol=1e-7)
    np.testing.assert_allclose(b.b, [0.10, 0.05], atol=1e-7)
    np.testing.assert_allclose(b.f, [-1.65, 0.665], atol=1e-7)
    assert fit.sigma < 1e-8


def test_oe_fit_on_noisy_data_is_unbiased_within_its_standard_deviations():
    """Output noise (std 0.1, 5% of the output's std) does not bias an OE fit (an ARX fit
    would be); the static gains land within 4 of their standard deviations."""
    U, y = _plant(6000, 0.1, seed=3)
    fit = fit_miso(U, y - y.mean(), [(0, 1, 1, 1), (1, 2, 2, 1)], skip=0)
    for pair, std, true in zip(fit.pairs, fit.gain_std, (3.0, 10.0), strict=True):
        assert abs(pair.static_gain - true) < 4 * std, (pair, std)
        assert std < 0.02 * abs(true)
    assert fit.sigma == pytest.approx(0.1, rel=0.05)
    assert fit.pairs[0].f[0] == pytest.approx(-0.85, abs=0.01)


def test_oe_fit_skips_lost_measurements():
    U, y = _plant(4000, 0.0)
    valid = np.ones(len(y), dtype=bool)
    valid[np.random.default_rng(1).choice(len(y), 400, replace=False)] = False
    y_lost = np.where(valid, y, 1e6)  # whatever is there must not count
    fit = fit_miso(U, y_lost - y[valid].mean(), [(0, 1, 1, 1), (1, 2, 2, 1)], skip=0,
                   valid=valid)
    np.testing.assert_allclose(fit.pairs[0].f, [-0.85], atol=1e-6)


def test_step_fit_tells_a_filtered_step_from_a_step():
    """The residual of an actuator fault (a step through G) has F^Du = F^; that of a sensor
    fault (a step) fitted with the same structure has F^Du far from F^ (the output-error paper's
    3.2)."""
    rng = np.random.default_rng(0)
    n, onset = 80, 20
    step = (np.arange(n) >= onset).astype(float)
    actuator = lfilter([0, 0.45], [1, -0.85], 0.002 * step) / 1e-4 + rng.standard_normal(n)
    sensor = 0.0095 * step / 1e-4 + rng.standard_normal(n)
    fa = fit_step(actuator, onset, 1, 1, 1, f_starts=(np.array([-0.85]),))
    assert fa.f[0] == pytest.approx(-0.85, abs=0.02)
    assert fa.static_gain == pytest.approx(0.002 * 3.0 / 1e-4, rel=0.03)
    fs = fit_step(sensor, onset - 1, 1, 1, 1, f_starts=(np.array([-0.85]),))
    assert abs(fs.f[0]) < 0.05  # a pure gain: |f^Du - f^| / |f^| ~ 1 >> kappa


def _diagnoser(settings: OeSettings | None = None) -> OutputErrorDiagnoser:
    opts = load_config(CONFIG).method_options
    from canfdi.methods.output_error.diagnoser import oe_thresholds

    s = settings or opts.settings
    return OutputErrorDiagnoser(opts.model, opts.sigma,
                                oe_thresholds(s.drift, s.false_alarm_interval, opts.long_run),
                                s, ["u1", "u2", "u3"], ["T1", "Omega2", "T3"])


def _run(name: str):
    from canfdi.firmware_sim.scenario import load_scenario
    from canfdi.firmware_sim.simulate import simulate

    return simulate(load_scenario(name))


def test_lost_values_make_only_their_residuals_missing():
    d = _diagnoser()
    run = _run("winding_machine_nominal")
    n = 600
    U, Z = run.u_c[:n].copy(), run.z[:n].copy()
    Z[400, 1] = np.nan  # Omega2 lost: only its residual
    U[450, 0] = np.nan  # u1 lost: T1 (its only path) missing for the path's settling time
    res = d.update_block(run.k[:n], (run.t[:n] * 1e9).astype(np.int64), U, Z).residuals
    warm = d.warmup
    assert np.isnan(res[:warm]).all() and not np.isnan(res[warm:400]).any()
    assert np.isnan(res[400, 1]) and not np.isnan(res[400, [0, 2]]).any()
    taint = settling_samples(0.85, d.settings.settle) + 1
    assert np.isnan(res[450:450 + taint, 0]).all() and not np.isnan(res[450 + taint, 0])
    assert not np.isnan(res[450:, 1:]).any()
    assert np.nanmax(np.abs(res[warm:] / d.sigma)) < 5.0  # the held input broke nothing


def test_a_transient_ends_unexplained_and_leaves_no_compensation():
    """One corrupt sample is detected but no step hypothesis fits it."""
    d = _diagnoser()
    run = _run("winding_machine_nominal")
    Z = run.z.copy()
    Z[1000, 0] += 0.01
    result = d.update_block(run.k, (run.t * 1e9).astype(np.int64), run.u_c, Z)
    assert [e.kind for e in result.events] == ["detected", "unexplained"]
    assert d.compensation == [] and d.mode == "monitor"


def test_reset_brings_the_residual_back_to_the_noise():
    """Section 3.3: after an accepted actuator fault the model outputs are recomputed from
    k_f, so the residual right after acceptance is noise (not the fault's response)."""
    d = _diagnoser()
    run = _run("winding_machine_actuator")
    result = d.update_block(run.k, (run.t * 1e9).astype(np.int64), run.u_c, run.z)
    acc = next(e for e in result.events if e.kind == "accepted")
    after = result.normalized[acc.sample + 1: acc.sample + 200]
    assert np.abs(after.mean(axis=0)).max() < 0.5
    assert np.abs(after).max() < 5.0
    assert d.compensation == [Compensation("actuator", 0, acc.onset_sample,
                                           lam=acc.estimates["lambda"])]


def test_pair_step_response_and_gain():
    pair = OePair(output=0, input=0, b=(0.45,), f=(-0.85,), delay=1)
    s = pair.step_response(200)
    assert s[0] == 0.0 and s[1] == pytest.approx(0.45)
    assert s[-1] == pytest.approx(pair.static_gain) and pair.static_gain == pytest.approx(3.0)


def _with(tmp_path, **changes):
    import yaml

    doc = read_yaml(CONFIG, ValueError, "config")
    for key, value in changes.items():
        target = doc["output_error"]
        *path, last = key.split("__")
        for p in path:
            target = target[int(p)] if p.isdigit() else target[p]
        target[last] = value
    out = tmp_path / "bad.yaml"
    out.write_text(yaml.safe_dump(doc))
    return load_config(out)


@pytest.mark.parametrize(("change", "field"), [
    ({"gamma": -1}, "output_error.gamma"),
    ({"kappa": "x"}, "output_error.kappa"),
    ({"min_samples": 1.5}, "output_error.min_samples"),
    ({"models__0__f": [-1.2]}, "output_error.models[0].f"),
    ({"models__0__output": "T9"}, "output_error.models[0].output"),
    ({"models__0__delay": -1}, "output_error.models[0].delay"),
    ({"models__0__gain_std": -0.1}, "output_error.models[0].gain_std"),
    ({"residual_std": [1e-4, 0.0, 1e-4]}, "output_error.residual_std"),
    ({"operating_point": {"u": [0.01]}}, "output_error.operating_point.u"),
    ({"bogus": 1}, "output_error.bogus"),
    ({"max_samples": 10}, "output_error.max_samples"),
])
def test_a_bad_output_error_section_names_the_field(tmp_path, change, field):
    with pytest.raises(ConfigError) as info:
        _with(tmp_path, **change)
    assert info.value.field == field


def test_identify_writes_each_gain_std_and_the_config_reads_it_back(tmp_path):
    """The fit's static-gain deviations go into the section and come back on the pairs: what
    an accepted actuator estimate adds to its variance for the model's uncertainty."""
    from canfdi.methods.output_error.config import output_error_section
    from canfdi.methods.output_error.model import OeModel, OePair

    config = load_config(CONFIG)
    assert all(p.gain_std > 0 for p in config.method_options.model.pairs)
    model = OeModel(pairs=(OePair(0, 0, (0.45,), (-0.85,), 1, gain_std=0.0016),),
                    u0=np.zeros(3), y0=np.zeros(3))
    section = output_error_section(model, np.full(3, 1e-4), np.ones(3), config.inputs,
                                   config.outputs)
    assert section["models"][0]["gain_std"] == 0.0016
    back = _with(tmp_path, models=section["models"]).method_options.model.pairs
    assert [p.gain_std for p in back] == [0.0016]
