"""`canfdi bench --quick --json` runs and reports every field (no timing is asserted)."""

import json
import math
import subprocess
import sys

import pytest

from tests.conftest import REPO

FIELDS = ("bus_limit_fps", "throughput_fps", "throughput_ratio", "decode_ratio_vs_cantools",
          "capture_ratio_vs_python_can", "replay_samples_per_s", "replay_samples_per_cpu_s",
          "replay_one_core_samples_per_s", "latency_p50_ms",
          "latency_p99_ms", "rss_growth_mib")


def test_bench_quick_json_is_complete():
    res = subprocess.run([sys.executable, "-m", "canfdi", "bench", "--quick", "--json",
                          "--frames", "30000"], capture_output=True, text=True, timeout=600,
                         cwd=REPO)
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    for field in FIELDS:
        assert isinstance(out[field], float) and math.isfinite(out[field]), field
    # Computed, not measured: 1 Mbit/s over the motor drive's 8, 8 and 4 byte frames.
    assert round(out["bus_limit_fps"]) == round(1e6 / ((111 + 111 + 79) / 3))
    assert out["bus_limit_stuffed_fps"] < out["bus_limit_fps"]
    assert out["throughput_ratio"] == out["throughput_fps"] / out["bus_limit_fps"]
    assert out["throughput_false_alarms"] == 0  # fault-free traffic
    assert out["latency_faults_diagnosed"] >= 1
    assert "canfdi bench [" in res.stderr  # progress reported
    from canfdi.core.kernel import available

    assert set(out["kernels"]) == set(available())  # every kernel built, side by side
    for row in out["kernels"].values():
        for key in ("monitor_fps", "faulty_fps", "assemble_fps", "assemble_damaged_fps"):
            assert math.isfinite(row[key]) and row[key] > 0, key
    # `canfdi run` as its own process, on udp_multicast: unless this host has no multicast
    # (said), the receive filters pass the drive's tenth of the frames and nothing else.
    if "daemon_error" not in out:
        filtered, unfiltered = out["daemon_filtered"], out["daemon_unfiltered"]
        assert 0 < filtered["frames_received"] < 0.25 * unfiltered["frames_received"]
        assert out["daemon_first_frame_s"] > 0 and out["daemon_rss_mib"] > 0
    else:
        assert out["daemon_error"]


def test_bench_rejects_too_few_frames():
    res = subprocess.run([sys.executable, "-m", "canfdi", "bench", "--frames", "10"],
                         capture_output=True, text=True, timeout=120, cwd=REPO)
    assert res.returncode == 2 and "--frames" in res.stderr


def test_bench_measures_the_bus_of_the_config_it_is_given():
    # The CiA 402 bus: SYNC (no data), three 6-byte PDOs a period, a 1-byte heartbeat every
    # tenth; the traffic is that bus's emulated drive, and the bus limit follows its frames.
    res = subprocess.run([sys.executable, "-m", "canfdi", "bench", "--quick", "--json",
                          "--frames", "20000", "--no-daemon", "--config",
                          str(REPO / "deploy" / "config" / "dc_motor_cia402.yaml")],
                         capture_output=True, text=True, timeout=600, cwd=REPO)
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout)
    assert out["scenario"] == "dc_motor_consecutive_cia402 without faults"
    assert out["frame_dlcs"] == [0, 1, 6]
    bits = (47 + 3 * (47 + 48) + 0.1 * (47 + 8)) / 4.1
    assert out["bus_limit_fps"] == pytest.approx(1e6 / bits, rel=2e-3)
    assert out["throughput_samples"] > 0.99 * 20000 / 4.1
    assert out["throughput_false_alarms"] == 0


def test_bench_without_a_scenario_for_the_bus_says_which_to_give(tmp_path):
    config = tmp_path / "three.yaml"
    text = (REPO / "deploy" / "config" / "dc_motor_two_drives_cia402.yaml").read_text()
    config.write_text(text.replace("  - {name: right, node: 2}",
                                   "  - {name: right, node: 2}\n  - {name: third, node: 3}"))
    res = subprocess.run([sys.executable, "-m", "canfdi", "bench", "--quick", "--config",
                          str(config)], capture_output=True, text=True, timeout=120, cwd=REPO)
    assert res.returncode == 2
    assert "no scenario" in res.stderr and "--scenario" in res.stderr
