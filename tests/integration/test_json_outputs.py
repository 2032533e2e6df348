"""--json on the verbs that report (issue 28): one object on stdout, with the keys their help
names; without it, words."""

from __future__ import annotations

import json

import pytest

from tests.cli import canfdi_main as main
from tests.conftest import REPO

CONFIG = REPO / "deploy" / "config" / "dc_motor.yaml"


def _json(capsys) -> dict:
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1, out
    return json.loads(out[0])


def test_export_run_capture_and_sim_print_one_object_with_json(tmp_path, capsys):
    log = tmp_path / "drive.log"
    assert main(["sim", "--scenario", "dc_motor_actuator", "--duration", "2", "-o", str(log),
                 "--quiet", "--json"]) == 0
    sim = _json(capsys)
    assert sim["frames"] == 600 and sim["output"] == str(log)
    assert main(["export", str(log), "-o", str(tmp_path / "drive.asc"), "--json",
                 "--no-progress"]) == 0
    export = _json(capsys)
    assert export == {"output": str(tmp_path / "drive.asc"), "format": "asc", "frames": 600,
                      "skipped": 0, "seconds": export["seconds"], "damage": []}
    assert main(["run", "--config", str(CONFIG), "--duration", "0.3", "--no-record",
                 "--quiet", "--json", "--channel", "canfdi-json-test"]) == 0
    run = _json(capsys)
    assert {"frames", "sent", "bus_errors", "bus_down_s", "faults", "gave_up"} <= set(run)
    assert run["frames"] == 0
    out = tmp_path / "capture.mcap"
    # A silent bus: nothing recorded, said, and exit 1 (issue 28: an empty .mcap and 0 before).
    assert main(["capture", "--config", str(CONFIG), "-o", str(out), "--duration", "0.3",
                 "--json", "--channel", "canfdi-json-test"]) == 1
    captured = capsys.readouterr()
    capture = json.loads(captured.out)
    assert capture["output"] is None and capture["frames"] == 0 and not out.exists()
    assert "no frame was received on virtual canfdi-json-test; nothing recorded" in captured.err


def test_a_bus_that_cannot_be_opened_ends_run_and_capture_with_1(tmp_path, capsys):
    """--retry-for (issue 28): a daemon on a bus that does not exist used to retry forever and
    exit 0; now it gives up after the bound, says so, and exits 1 (systemd restarts it)."""
    # lo exists but is no CAN interface: opening a CAN socket on it fails (or this kernel
    # has no SocketCAN at all), as a bus that is down does.
    bad = ["-i", "socketcan", "-c", "lo", "--retry-for", "0.5"]
    assert main(["run", "--config", str(CONFIG), "--no-record", "--quiet", "--json", *bad]) == 1
    captured = capsys.readouterr()
    assert json.loads(captured.out)["gave_up"] is True and "giving up" in captured.err
    out = tmp_path / "c.mcap"
    assert main(["capture", "--config", str(CONFIG), "-o", str(out), *bad]) == 1
    assert "the bus could not be opened" in capsys.readouterr().err and not out.exists()


def test_sim_says_words_without_json(tmp_path, capsys):
    assert main(["sim", "--scenario", "dc_motor_actuator", "--duration", "1", "-o",
                 str(tmp_path / "d.log"), "--quiet"]) == 0
    out = capsys.readouterr().out.strip()
    assert out == f"canfdi sim: dc_motor_actuator: 100 samples, 300 frames -> {tmp_path / 'd.log'}"


@pytest.mark.parametrize("verb", ["run", "capture", "sim"])
@pytest.mark.parametrize("bus", [["-i", "socketcn"], ["-i", "socketcan", "-c", "canfdi-nosuch0"]])
def test_an_unknown_interface_or_a_channel_that_is_not_there_is_one_line_and_2(
        tmp_path, capsys, verb, bus):
    args = {"run": ["run", "--config", str(CONFIG), "--no-record"],
            "capture": ["capture", "--config", str(CONFIG), "-o", str(tmp_path / "c.mcap")],
            "sim": ["sim", "--scenario", "dc_motor_actuator", "--duration", "1"]}[verb]
    assert main([*args, *bus]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert ("did you mean 'socketcan'?" in err if bus[1] == "socketcn"
            else "no network interface 'canfdi-nosuch0'" in err)
