"""The monitor learns its drive (issue 16): teach-in on a live run, and the noise watchdog.

- `Monitor(teach=Teach(...))` (what `canfdi run --teach` builds) records the first samples
  without diagnosing them (FDI_STATUS "teaching"), learns the noise as `canfdi calibrate` does,
  writes the learned values to the log's metadata, then diagnoses with them: a DC motor twice
  as noisy as its config, taught for 20 s, diagnoses the shipped consecutive faults right.
- The watchdog: a DC motor whose sensors become twice as noisy mid-run is said to be in
  mismatch within the watchdog's window (status, event, log metadata untouched), no fault is
  raised, and detection keeps its false-alarm interval after (no alarm storm).
"""

from __future__ import annotations

import dataclasses

import cantools
import numpy as np
import pytest
import yaml

from canfdi.config import load_config
from canfdi.firmware_sim.scenario import load_scenario
from canfdi.firmware_sim.simulate import simulate
from canfdi.monitor import Monitor
from canfdi.tools.calibrate import Teach
from tests.conftest import REPO, events_by_chunking

CONFIG = REPO / "deploy" / "config" / "dc_motor.yaml"
STATUS = cantools.database.load_file(REPO / "dbc" / "canfdi_monitor.dbc")


class MetadataSink:
    """The part of a record sink teach-in uses, and no-ops for the rest."""

    def __init__(self) -> None:
        self.metadata: dict[str, dict[str, str]] = {}

    def write_metadata(self, name, values):
        self.metadata[name] = values

    def __getattr__(self, name):
        return lambda *args, **kwargs: None


def _state(monitor: Monitor) -> int:
    frame = monitor.status_frames()[0]
    return STATUS.decode_message(frame.frame_id, frame.data, decode_choices=False)["State"]


def _feed(monitor, k, U, Z, block=500):
    dt_ns = round(monitor.dt * 1e9)
    for i in range(0, len(k), block):
        s = slice(i, i + block)
        monitor.on_samples(k[s], k[s] * dt_ns, U[s], Z[s], np.zeros(len(k[s]), dtype=np.int64))
        yield int(k[s][-1])


def test_teach_in_learns_a_twice_as_noisy_drive_then_diagnoses_its_faults():
    shipped = load_scenario("dc_motor_consecutive")
    # Seconds of healthy drive to learn from, before the shipped faults: two periods of the
    # speed reference's square wave, so each fault meets the drive as in the shipped scenario.
    lead = 16.0
    scenario = dataclasses.replace(
        shipped, measurement_std=2.0 * shipped.measurement_std, duration=shipped.duration + lead,
        faults=tuple(dataclasses.replace(f, onset=f.onset + lead) for f in shipped.faults))
    run = simulate(scenario)
    config = load_config(CONFIG)
    teach = Teach(config, yaml.safe_load(CONFIG.read_text()), samples=1600)
    sink = MetadataSink()
    monitor = Monitor(config, sink=sink, record_residuals=False, teach=teach)
    states = {}
    for last in _feed(monitor, run.k, run.u_c, run.z):
        states[last] = _state(monitor)
    assert all(s == 5 for k, s in states.items() if k < 1599)  # "teaching"
    assert 5 not in {s for k, s in states.items() if k >= 1599}
    learned = sink.metadata["canfdi.teach.dc_motor"]
    assert learned["status"] == "learned" and learned["samples"] == "1600"
    noise = yaml.safe_load(learned["noise_json"])
    np.testing.assert_allclose([n["std"] for n in noise], 0.02, rtol=0.1)
    assert monitor.events[0].kind == "taught"
    faults = monitor.summary()["faults"]
    truth = [(f.target, f.index) for f in scenario.faults]
    assert [(f["kind"], f["index"]) for f in faults][:2] == truth[:2]
    # The third (an i_a bias) is told only up to its twin i_f_plus_i_a (see the scenario).
    third = faults[2]
    assert (third["kind"], third["index"]) == truth[2] or any(
        (c["target"], c["index"]) == truth[2] for c in third["candidates"])
    assert not monitor.summary()["unexplained"] and not monitor.summary()["mismatches"]


def test_teach_in_on_a_faulty_start_says_so_and_monitors_as_configured():
    run = simulate(dataclasses.replace(load_scenario("dc_motor_consecutive"), duration=25.0))
    config = load_config(CONFIG)
    teach = Teach(config, yaml.safe_load(CONFIG.read_text()), samples=1500)  # fault at 1000
    sink = MetadataSink()
    monitor = Monitor(config, sink=sink, record_residuals=False, teach=teach)
    list(_feed(monitor, run.k, run.u_c, run.z))
    learned = sink.metadata["canfdi.teach.dc_motor"]
    assert learned["status"] == "failed" and "fault" in learned["reason"]
    assert monitor.events[0].kind == "teach_failed"
    # Monitoring goes on with the config's noise (the fault already there is an offset from
    # the first residual on: detected, whatever its diagnosis makes of it).
    assert monitor.drives[0].diagnoser.last_residuals is not None
    assert _state(monitor) != 5
    assert any(e.kind == "detected" for e in monitor.events)


@pytest.mark.parametrize("seed", [1, 4])
def test_the_watchdog_flags_a_doubled_noise_and_raises_no_fault(seed):
    scenario = dataclasses.replace(load_scenario("dc_motor_nominal"), seed=seed, duration=240.0)
    run = simulate(scenario)
    config = load_config(CONFIG)
    Z = run.z.copy()
    k0 = len(run.k) // 4
    rng = np.random.default_rng(seed)
    Z[k0:] += rng.standard_normal(Z[k0:].shape) * scenario.measurement_std * np.sqrt(3.0)
    monitor = Monitor(config, record_residuals=False)
    states = {last: _state(monitor) for last in _feed(monitor, run.k, run.u_c, Z)}
    events = monitor.events
    first = next(e for e in events if e.kind == "mismatch")
    window = config.watchdog.block * (config.watchdog.blocks + 1)  # the change falls mid-block
    assert k0 < first.sample <= k0 + window
    assert all(v == pytest.approx(2.0, rel=0.25) for v in first.estimates.values())
    assert not [e for e in events if e.kind in ("accepted", "refined", "unexplained")]
    assert not [e for e in events if e.kind == "detected"]  # nor after: no storm
    assert all(s == 6 for k, s in states.items() if k > first.sample)  # "mismatch"
    # "checking" while the watchdog checks the config's noise on its first two blocks (the
    # run starts at k = 0, a block's start), then "monitoring".
    assert int(run.k[0]) % config.watchdog.block == 0
    armed = config.watchdog.blocks * config.watchdog.block
    assert all(s == (8 if k < armed else 1) for k, s in states.items() if k < k0)
    assert any(k < armed for k in states) and any(armed <= k < k0 for k in states)


def test_run_refuses_a_teach_in_too_short_to_learn_from():
    import subprocess
    import sys

    res = subprocess.run([sys.executable, "-m", "canfdi", "run", "--config", str(CONFIG),
                          "--teach", "2", "--no-record"], capture_output=True, text=True,
                         timeout=120, check=False)
    assert res.returncode == 2
    assert "--teach: 2 s is 200 samples" in res.stderr and "at least 1000" in res.stderr


def test_the_live_view_says_mismatch_and_teaching():
    from canfdi.liveview import snapshot

    config = load_config(CONFIG)
    teach = Teach(config, yaml.safe_load(CONFIG.read_text()), samples=1000)
    assert snapshot(Monitor(config, teach=teach))["state"] == "teaching"
    monitor = Monitor(config, record_residuals=False)
    assert snapshot(monitor)["state"] == "checking"
    run = simulate(dataclasses.replace(load_scenario("dc_motor_nominal"), duration=6.0))
    list(_feed(monitor, run.k, run.u_c, run.z))  # the first watchdog window ends the check
    assert snapshot(monitor)["state"] == "monitoring"
    watchdog = monitor.drives[0].diagnoser.watchdog
    watchdog.mismatch[1] = True  # what the watchdog test above reaches
    watchdog.ratio[:] = 2.0
    assert snapshot(monitor)["state"] == "mismatch"
    watchdog.ratio[:] = 0.5
    assert snapshot(monitor)["state"] == "quiet"


def test_the_watchdog_gives_the_same_verdicts_sample_by_sample_and_in_blocks():
    scenario = dataclasses.replace(load_scenario("dc_motor_nominal"), seed=2, duration=60.0)
    run = simulate(scenario)
    Z = run.z.copy()
    Z[2000:] += np.random.default_rng(2).standard_normal(Z[2000:].shape) * 0.02
    Z[4500:] = run.z[4500:]  # and back
    results = events_by_chunking(load_config(CONFIG), run.k, run.u_c, Z)
    kinds = [kind for kind, *_ in results[0]]
    assert "mismatch" in kinds and "matched" in kinds
    assert results[1] == results[0] and results[2] == results[0]
