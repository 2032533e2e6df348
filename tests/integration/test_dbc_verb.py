"""`canfdi dbc`: the DBC of the monitor's frames as a config sends them, which cantools (not
canfdi) loads and decodes a demo's fault frames with, the drives' frames too when merged."""

import cantools
import numpy as np
import pytest
from canfdi.configs import CONFIG_DIR

from canfdi.io.reader import read_frames
from tests.cli import canfdi_main as main


@pytest.fixture(scope="module")
def cia402_demo(tmp_path_factory):
    """A demo of the two CiA 402 drives (the monitor's frames moved to bus.monitor.base
    0x680) and the merged DBC of its config."""
    d = tmp_path_factory.mktemp("dbc")
    log, dbc = d / "demo.mcap", d / "bus.dbc"
    assert main(["demo", "--no-live", "--json", "--scenario", "dc_motor_two_drives_cia402",
                 "-o", str(log)]) == 0
    assert main(["dbc", "--config", str(CONFIG_DIR / "dc_motor_two_drives_cia402.yaml"),
                 "--merge", "-o", str(dbc)]) == 0
    return read_frames(log), cantools.database.load_file(dbc)


def test_cantools_decodes_the_demos_fault_frames_at_the_configs_ids(cia402_demo):
    frames, database = cia402_demo
    sent = frames.select(frames.status == "sent")
    names = [database.get_message_by_frame_id(i).name for i in sent.id.tolist()]
    assert set(names) >= {"FDI_FAULT", "FDI_ESTIMATE", "FDI_STATUS"}
    assert database.get_message_by_name("FDI_FAULT").frame_id == 0x680
    decoded = [database.decode_message(i, d) for i, d in zip(sent.id.tolist(), sent.payloads(),
                                                               strict=True)]
    faults = [m for m, name in zip(decoded, names, strict=True) if name == "FDI_FAULT"]
    assert {str(m["State"]) for m in faults} >= {"detected", "accepted"}
    assert {int(m["Drive"]) for m in faults} <= {0, 1}
    # The drives' own frames decode with the same file (node 1's PDOs as the EDS writes them).
    received = frames.select(frames.status == "ok")
    node1 = received.id == 0x181
    assert node1.any()
    first = int(np.flatnonzero(node1)[0])
    assert database.decode_message(0x181, received.payloads()[first])


def test_without_merge_only_the_monitors_messages_at_the_config_ids(capsys):
    assert main(["dbc", "--config", str(CONFIG_DIR / "dc_motor.yaml")]) == 0
    database = cantools.database.load_string(capsys.readouterr().out, "dbc")
    assert [(m.name, m.frame_id) for m in database.messages] == [
        ("FDI_FAULT", 0x80), ("FDI_ESTIMATE", 0x81), ("FDI_STATUS", 0x82),
        ("FDI_RESIDUAL", 0x83)]
    status = database.get_message_by_name("FDI_STATUS")
    assert "E2E profile canfdi" in status.comment
    assert status.get_signal_by_name("State").choices[7] == "no_traffic"


def test_a_config_still_to_identify_will_do_and_bad_input_is_one_line(tmp_path, capsys):
    assert main(["dbc", "--config", str(CONFIG_DIR / "servo_axis_odrive.yaml"), "--merge",
                 "-o", str(tmp_path / "odrive.dbc")]) == 0
    assert "FDI_STATUS" in {m.name for m in cantools.database.load_file(
        tmp_path / "odrive.dbc").messages}
    capsys.readouterr()
    assert main(["dbc", "--config", str(tmp_path / "missing.yaml")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "missing.yaml" in err
    assert main(["dbc", "--config", str(CONFIG_DIR / "dc_motor.yaml"), "-o",
                 str(tmp_path / "no" / "dir" / "x.dbc")]) == 2
    assert capsys.readouterr().err.startswith("canfdi dbc: cannot write")
