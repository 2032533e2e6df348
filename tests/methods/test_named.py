"""NAMED, then identified (issue 41): a scale fault on an actuator under a constant command acts
as an offset, and the data cannot tell it from a bias until the command moves. The monitor names
the actuator within a few samples of the onset (its offset now, the form undecided), says so on
FDI_STATUS and FDI_FAULT, and accepts the scale once the command has moved."""

from __future__ import annotations

import cantools
import numpy as np
import pytest

from canfdi.core.calibrate import threshold_for_long_run_variance
from canfdi.core.design import DesignOptions, design_bank
from canfdi.core.model import StateSpace
from canfdi.core.records import Sample
from canfdi.core.supervision import Supervision
from canfdi.methods.parity.diagnoser import ParityDiagnoser, ParitySettings
from tests.conftest import REPO

ONSET, MOVES, ETA = 1000, 1600, 1.2


def _diagnoser() -> ParityDiagnoser:
    model = StateSpace(A=[[0.9]], B=[[1.0]], C=[[1.0], [1.0]], dt=0.01)  # two sensors of x
    design = design_bank(model, ["u"], ["y0", "y1"],
                         DesignOptions(measurement_std=np.array([0.01, 0.01])))
    return ParityDiagnoser(design, ParitySettings(),
                           threshold_for_long_run_variance(0.5, 1e7, np.ones(3)))


def _samples(n: int = 3000):
    """The command holds at 1 until MOVES, then steps between -1 and 1 every 40 samples; from
    ONSET the actuator gives ETA times it."""
    rng = np.random.default_rng(0)
    x = 0.0
    for k in range(n):
        uc = 1.0 if k < MOVES or (k // 40) % 2 else -1.0
        yield Sample(k, k * 10_000_000, np.array([uc]), x + 0.01 * rng.standard_normal(2))
        x = 0.9 * x + (ETA if k >= ONSET else 1.0) * uc


def test_a_scale_under_a_constant_command_is_named_at_once_and_accepted_once_it_moves():
    supervisor = Supervision(_diagnoser())
    events, states = [], {}
    for sample in _samples():
        events += supervisor.update(sample)
        states[sample.k] = supervisor.state
    kinds = [e.kind for e in events if e.kind != "refined"]
    assert kinds == ["detected", "named", "accepted"], events
    _, named, accepted = (e for e in events if e.kind != "refined")
    assert (named.target, named.name) == ("actuator", "u")
    assert named.sample - ONSET <= 15
    # The offset the scale acts as under the command of 1: ETA - 1.
    assert named.estimates == {"lambda": pytest.approx(ETA - 1.0, abs=0.01)}
    assert "form" in named.undecided
    assert named.variances["lambda"] > 0.0
    # Accepted once the command moved, as the scale it is.
    assert MOVES < accepted.sample < MOVES + 100
    assert accepted.estimates["eta"] == pytest.approx(ETA, abs=0.005)
    assert accepted.estimates["lambda"] == pytest.approx(0.0, abs=0.01)
    # The drive's state says so meanwhile.
    assert states[named.sample - 1] == "diagnosing"
    assert {states[k] for k in range(named.sample, accepted.sample)} == {"named"}
    assert states[accepted.sample] == "monitoring"


def test_the_monitor_dbc_names_the_named_states():
    db = cantools.database.load_file(REPO / "dbc" / "canfdi_monitor.dbc")
    fault = db.get_message_by_name("FDI_FAULT").get_signal_by_name("State")
    status = db.get_message_by_name("FDI_STATUS").get_signal_by_name("State")
    assert fault.choices[2] == "named" and status.choices[10] == "named"
