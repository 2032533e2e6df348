"""The vectorised ensemble is Simulator.advance's arithmetic for K runs at once; its runs differ."""

import numpy as np
import pytest

from canfdi.firmware_sim.ensemble import PRBS_PERIOD, DcMotorEnsemble, prbs_sequence
from canfdi.firmware_sim.plants.dc_motor import DcMotor
from canfdi.firmware_sim.scenario import load_scenario, parse_scenario
from canfdi.firmware_sim.simulate import Simulator

# Long enough for several reference steps (every 400 samples) and the start-up transient.
N = 1500


def _ensemble_run(ens: DcMotorEnsemble, run: int, chunks: list[int]):
    """(z, u_c, x) of one run over consecutive chunks, each (sum(chunks), ·)."""
    parts = [ens.advance(c) for c in chunks]
    return tuple(np.concatenate([getattr(p, f)[run] for p in parts]) for f in ("z", "u_c", "x"))


def test_one_run_equals_simulator_advance_for_the_nominal_scenario():
    scenario = load_scenario("dc_motor_nominal")
    sim = Simulator(scenario).advance(N)
    # Chunked on purpose: noise is drawn per chunk, and must still be the Simulator's stream.
    z, u_c, x = _ensemble_run(DcMotorEnsemble.from_scenario(scenario, 1), 0, [1, 499, 1000])
    np.testing.assert_allclose(z, sim.z, rtol=0, atol=1e-12)
    np.testing.assert_allclose(u_c, sim.u_c, rtol=0, atol=1e-12)
    np.testing.assert_allclose(x, sim.x, rtol=0, atol=1e-12)


def test_one_run_equals_simulator_advance_with_process_noise():
    """Process noise interleaves n draws after the q measurement draws of each sample."""
    scenario = parse_scenario({"plant": "dc_motor", "duration": 20.0, "seed": 11,
                               "noise": {"measurement": 0.02, "process": [0.001, 0.01, 0.05]}})
    sim = Simulator(scenario).advance(N)
    z, u_c, x = _ensemble_run(DcMotorEnsemble.from_scenario(scenario, 1), 0, [700, 800])
    np.testing.assert_allclose(z, sim.z, rtol=0, atol=1e-12)
    np.testing.assert_allclose(u_c, sim.u_c, rtol=0, atol=1e-12)
    np.testing.assert_allclose(x, sim.x, rtol=0, atol=1e-12)


def test_shapes_follow_the_docstring():
    chunk = DcMotorEnsemble(3, 0, measurement_std=0.01).advance(10)
    assert chunk.k.shape == (10,) and chunk.runs == 3 and len(chunk) == 10
    assert chunk.z.shape == (3, 10, 4) and chunk.u_c.shape == (3, 10, 1)
    assert chunk.x.shape == (3, 10, 3)
    assert list(DcMotorEnsemble(3, 0, measurement_std=0.01).advance(5).k) == [0, 1, 2, 3, 4]


def test_runs_differ_in_noise_and_dither():
    K = 4
    ens = DcMotorEnsemble(K, 3, measurement_std=0.01)
    assert len(set(ens.dither_offsets.tolist())) == K and ens.dither_offsets[0] == 0
    chunk = ens.advance(500)
    for a in range(K):
        for b in range(a + 1, K):
            assert not np.allclose(chunk.z[a], chunk.z[b])
            noise_a = chunk.z[a, :, 2] - chunk.z[a, :, 0] - chunk.z[a, :, 1]  # y3 - y1 - y2 = 0
            noise_b = chunk.z[b, :, 2] - chunk.z[b, :, 0] - chunk.z[b, :, 1]
            assert abs(np.corrcoef(noise_a, noise_b)[0, 1]) < 0.2
            # Same dither: commands within a fraction of a volt; different: 16 V apart about
            # half the time.
            assert np.mean(np.abs(chunk.u_c[a, :, 0] - chunk.u_c[b, :, 0]) > 8.0) > 0.3


def test_run_i_does_not_depend_on_k_and_can_be_replayed_alone():
    seed, K, i = 9, 5, 3
    many = DcMotorEnsemble(K, seed, measurement_std=0.01).advance(300)
    first = DcMotorEnsemble(1, seed, measurement_std=0.01).advance(300)
    np.testing.assert_array_equal(many.z[0], first.z[0])  # child 0 whatever K
    alone = DcMotorEnsemble(1, measurement_std=0.01,
                            noise_seeds=[np.random.SeedSequence(seed).spawn(i + 1)[i]],
                            dither_offsets=[i * PRBS_PERIOD // K]).advance(300)
    np.testing.assert_array_equal(many.z[i], alone.z[0])
    np.testing.assert_array_equal(many.u_c[i], alone.u_c[0])


def test_prbs_is_the_controller_lfsr_with_period_65535():
    ctrl = DcMotor().controller()
    seq = prbs_sequence(length=2 * PRBS_PERIOD)
    assert [ctrl._prbs() for _ in range(1000)] == seq[:1000].tolist()
    np.testing.assert_array_equal(seq[:PRBS_PERIOD], seq[PRBS_PERIOD:])
    for divisor in (3, 5, 17, 257):  # 65535 = 3 * 5 * 17 * 257: no shorter period
        shift = PRBS_PERIOD // divisor
        assert not np.array_equal(seq[:PRBS_PERIOD], seq[shift:shift + PRBS_PERIOD])


def test_bad_arguments_are_named():
    with pytest.raises(ValueError, match="faults"):
        DcMotorEnsemble.from_scenario(load_scenario("dc_motor_actuator"), 2)
    with pytest.raises(ValueError, match="plant"):
        DcMotorEnsemble.from_scenario(load_scenario("vtol_nominal"), 2)
    with pytest.raises(ValueError, match="runs"):
        DcMotorEnsemble(0, measurement_std=0.01)
    with pytest.raises(ValueError, match="dither_offsets"):
        DcMotorEnsemble(2, measurement_std=0.01, dither_offsets=[0])
    with pytest.raises(ValueError, match="measurement_std"):
        DcMotorEnsemble(2, measurement_std=-1.0)
