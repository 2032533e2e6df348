"""Re-detection of an accepted fault refines it (issue 16): every built-in method, on its
example plant, with a sensor bias whose size grows by a tenth after it was accepted (what an
inexact estimate leaves behind looks the same to the monitor). The second diagnosis must be a
"refined" event with the channel's new total, the compensation must hold it, and no new fault
may be raised; the monitor announces it with FDI_ESTIMATE frames only."""

from __future__ import annotations

import cantools
import numpy as np
import pytest

from canfdi import methods
from canfdi.config import parse_config
from canfdi.core.records import compensated
from canfdi.firmware_sim.plants import make_plant
from canfdi.firmware_sim.scenario import parse_scenario
from canfdi.firmware_sim.simulate import simulate
from canfdi.monitor import Monitor
from tests.conftest import REPO
from tests.methods.conftest import _plant_of, example_document

ONSET, GROWS = 800, 3000


def _run(method: str):
    path, doc = example_document(method)
    config = parse_config(doc, path)
    plant = _plant_of(config)
    noise = make_plant(plant).noise_defaults().measurement
    dt = config.model.dt or 0.01
    bias = 40.0 * float(noise[0])
    run = simulate(parse_scenario({
        "plant": plant, "duration": 6000 * dt, "seed": 5,
        "faults": [{"target": "sensor", "index": 0, "onset": ONSET * dt, "bias": bias}]}))
    Z = run.z.copy()
    Z[run.k >= GROWS, 0] += 0.1 * bias
    return config, run.k, (run.k * round(dt * 1e9)).astype(np.int64), run.u_c, Z, bias


@pytest.mark.parametrize("method", ["parity", "output_error", "uio"])
def test_a_fault_that_grows_after_acceptance_is_refined_not_raised_again(method):
    config, k, t_ns, U, Z, bias = _run(method)
    dg = methods.build_diagnoser(config)
    events = dg.update_block(k, t_ns, U, Z).events
    decisions = [e for e in events if e.kind != "detected"]
    # Refinements by the parity method's tracker (detected_sample None: no re-detection) may
    # come before; the growth's own diagnosis is the first refinement of a detection.
    redetected = [e for e in decisions if e.kind == "accepted" or e.detected_sample is not None]
    assert [e.kind for e in redetected][:2] == ["accepted", "refined"], decisions
    first, refined = redetected[:2]
    assert (first.target, first.index) == (refined.target, refined.index) == ("sensor", 0)
    assert first.estimates["bias"] == pytest.approx(bias, rel=0.05)
    assert refined.estimates["bias"] == pytest.approx(1.1 * bias, rel=0.05)
    assert refined.onset_sample == pytest.approx(GROWS, abs=10)
    # No new fault, ever: every later decision refines the same channel.
    assert all(e.kind == "refined" and e.index == 0 for e in decisions[1:]), decisions
    assert compensated(dg.compensation, "sensor", 0)["bias"] == pytest.approx(
        decisions[-1].estimates["bias"])


def test_the_monitor_announces_a_refinement_with_estimates_only():
    config, k, t_ns, U, Z, bias = _run("parity")
    monitor = Monitor(config, record_residuals=False)
    frames = monitor.on_samples(k, t_ns, U, Z, np.zeros(len(k), dtype=np.int64))
    db = cantools.database.load_file(REPO / "dbc" / "canfdi_monitor.dbc")
    decoded = [(db.get_message_by_frame_id(f.frame_id).name,
                db.decode_message(f.frame_id, f.data, decode_choices=False)) for f in frames]
    faults = [d for name, d in decoded if name == "FDI_FAULT"]
    # Two FDI_FAULT frames (detected, accepted) for the fault; the re-detection's "detected"
    # is the third; the refinement sends none.
    assert [d["State"] for d in faults] == [1, 3, 1]
    estimates = [d["Value"] for name, d in decoded if name == "FDI_ESTIMATE" and d["Param"] == 2]
    # The accepted estimate, then the refinements (the tracker's and the re-detection's),
    # each the channel's total: the last one holds the grown bias.
    assert estimates[0] == pytest.approx(bias, rel=0.05)
    assert estimates[-1] == pytest.approx(1.1 * bias, rel=0.05)
    summary = monitor.summary()
    assert len(summary["faults"]) == 1 and len(summary["refined"]) == len(estimates) - 1
    assert monitor.status_frames()  # one channel active, whatever the entries
    status = db.decode_message(monitor.status_frames()[0].frame_id,
                               monitor.status_frames()[0].data, decode_choices=False)
    assert status["ActiveFaults"] == 1
