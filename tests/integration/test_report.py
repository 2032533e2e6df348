"""`canfdi report`: the PNG figures and the HTML page of a demo log; bad input exits 2."""

import json
import subprocess
import sys

import numpy as np
import pytest

from canfdi.config import load_config
from canfdi.firmware_sim.emitter import frame_log
from canfdi.firmware_sim.scenario import load_scenario
from canfdi.io.writer import McapRecorder
from canfdi.monitor import Monitor
from canfdi.tools.report import decimate
from tests.cli import canfdi_main as main
from tests.conftest import REPO

CONFIG = REPO / "deploy" / "config" / "dc_motor.yaml"
PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def demo_log(tmp_path_factory):
    log = tmp_path_factory.mktemp("report") / "actuator.mcap"
    res = subprocess.run([sys.executable, "-m", "canfdi", "demo", "--scenario",
                          "dc_motor_actuator", "-o", str(log), "--json"],
                         capture_output=True, text=True, timeout=120, cwd=REPO)
    assert res.returncode == 0, res.stderr
    return log


def test_report_writes_the_pngs_and_the_html_for_a_demo_log(demo_log, tmp_path):
    out = tmp_path / "rep"
    res = subprocess.run([sys.executable, "-m", "canfdi", "report", str(demo_log), "-o",
                          str(out), "--json"], capture_output=True, text=True, timeout=120,
                         cwd=REPO)
    assert res.returncode == 0, res.stderr
    result = json.loads(res.stdout)
    assert result["missing"] == []
    names = {p.split("/")[-1] for p in result["figures"]}
    assert names == {"overview.png", "residuals.png", "fault_1_actuator_V.png"}
    for name in names:
        data = (out / name).read_bytes()
        assert data.startswith(PNG) and len(data) > 20_000, name
    (fault,) = result["faults"]
    assert fault["name"] == "V" and fault["figure"] == "fault_1_actuator_V.png"
    assert fault["truth"] == {"eta": 2.0, "lambda": 10.0}
    assert abs(fault["error"]["eta"]) < 0.05 and abs(fault["error"]["lambda"]) < 0.5
    # The trajectory recomputed from the log's residuals ends on the accepted estimate.
    assert fault["trajectory_mismatch"] < 1e-9
    page = (out / "index.html").read_text()
    for name in names:
        assert f'src="{name}"' in page
    assert "<td>V</td>" in page and "actuator 0" in page
    eta, lam = fault["estimate"]["eta"], fault["estimate"]["lambda"]
    assert f"η = {eta:.5g}" in page and f"λ = {lam:.5g}" in page
    assert "η = 2, λ = 10" in page  # the truth column


def test_report_bad_input_exits_2(tmp_path, capsys):
    assert main(["report", str(tmp_path / "nope.mcap"), "-o", str(tmp_path / "a")]) == 2
    assert "no such log" in capsys.readouterr().err
    text = tmp_path / "notes.mcap"
    text.write_text("not a log\n")
    assert main(["report", str(text), "-o", str(tmp_path / "b")]) == 2
    assert "not an MCAP file" in capsys.readouterr().err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_report_of_a_log_without_residuals_says_what_is_missing(tmp_path, capsys):
    # A capture-style log: samples decoded and recorded, no diagnosis, no residuals.
    config = load_config(CONFIG)
    frames = frame_log(load_scenario("dc_motor_actuator"), duration=3.0)
    monitor = Monitor(config, diagnose=False)
    log = tmp_path / "cap<&>.mcap"
    with McapRecorder(log, metadata=monitor.metadata()) as recorder:
        monitor.sink = recorder
        monitor.on_frames(frames.frames)
    out = tmp_path / "rep"
    assert main(["report", str(log), "-o", str(out), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert "no residuals" in err and "no accepted fault" in err
    assert "canfdi replay LOG -o diagnosed.mcap" in err
    assert (out / "overview.png").read_bytes().startswith(PNG)
    assert not (out / "residuals.png").exists()
    page = (out / "index.html").read_text()
    assert "cap&lt;&amp;&gt;.mcap" in page and "cap<&>" not in page
    assert "no residuals" in page and 'src="overview.png"' in page


def test_decimate_keeps_extremes_within_the_point_budget():
    k = np.arange(1_000_000)
    y = np.zeros((len(k), 2))
    y[123_457, 0], y[654_321, 1] = 50.0, -7.0
    y[10, 1] = np.nan
    x, yd = decimate(k, y, max_points=5000)
    assert len(x) <= 5000 and yd.shape == (len(x), 2)
    assert yd[:, 0].max() == 50.0 and yd[:, 1].min() == -7.0
    assert np.all(np.diff(x) >= 0)
    short_x, short_y = decimate(k[:100], y[:100])
    assert len(short_x) == 100 and short_y.shape == (100, 2)
