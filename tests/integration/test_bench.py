"""`canfdi bench --quick --json` runs and reports every field (no timing is asserted)."""

import json
import math
import subprocess
import sys

from tests.conftest import REPO

FIELDS = ("bus_limit_fps", "throughput_fps", "throughput_ratio", "decode_ratio_vs_cantools",
          "capture_ratio_vs_python_can", "replay_samples_per_s", "latency_p50_ms",
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


def test_bench_rejects_too_few_frames():
    res = subprocess.run([sys.executable, "-m", "canfdi", "bench", "--frames", "10"],
                         capture_output=True, text=True, timeout=120, cwd=REPO)
    assert res.returncode == 2 and "--frames" in res.stderr
