"""Logs that leave nothing usable end non-zero with one line, and a run never deletes a file it
did not write (issue 27)."""

from __future__ import annotations

import pytest

from canfdi.config import load_config
from canfdi.core.kernel import ENV, available
from canfdi.io.writer import McapRecorder
from canfdi.monitor import Monitor
from tests.cli import canfdi_main as main
from tests.conftest import REPO

CONFIG = REPO / "deploy" / "config" / "dc_motor.yaml"


@pytest.fixture(autouse=True, params=available())
def kernel(request, monkeypatch):
    """Every test on every kernel built (the verbs and the Monitor resolve it from the
    environment): the C kernel meets the same hostile logs as numpy."""
    monkeypatch.setenv(ENV, request.param)
    return request.param


def test_demo_never_deletes_a_segment_it_did_not_write(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "x-0001.mcap").write_text("someone's file")
    assert main(["demo", "-o", "x.mcap", "--no-live"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "x-0001.mcap exists" in err[0]
    assert (tmp_path / "x-0001.mcap").read_text() == "someone's file"
    assert not (tmp_path / "x.mcap").exists()


def test_export_of_a_log_without_frames_is_one_line_exit_1_and_no_file(tmp_path, capsys):
    log = tmp_path / "empty.log"
    log.write_text("")
    out = tmp_path / "out.csv"
    assert main(["export", str(log), "-o", str(out), "--no-progress"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no frame to export" in err[0]
    assert not out.exists()


def test_report_of_a_log_without_samples_is_one_line_exit_1_and_no_page(tmp_path, capsys):
    log = tmp_path / "nothing.mcap"
    McapRecorder(log, metadata=Monitor(load_config(CONFIG)).metadata()).close()
    out = tmp_path / "report"
    assert main(["report", str(log), "-o", str(out), "--no-progress"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nothing to report" in err[0]
    assert not out.exists()


def test_a_cut_blf_is_said_with_what_its_header_announces(tmp_path, capsys):
    import json

    from canfdi.firmware_sim.emitter import frame_log
    from canfdi.firmware_sim.scenario import load_scenario
    from canfdi.io.logs import write_frames

    frames = frame_log(load_scenario("dc_motor_actuator"), duration=8.0).frames
    whole = tmp_path / "run.blf"
    write_frames(whole, [frames])
    cut = tmp_path / "cut.blf"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size // 2])
    assert main(["replay", str(whole), "--config", str(CONFIG), "--json", "--no-progress"]) == 0
    clean = json.loads(capsys.readouterr().out)
    assert clean["damage"] == []
    assert main(["replay", str(cut), "--config", str(CONFIG), "--json", "--no-progress"]) == 0
    captured = capsys.readouterr()
    result = json.loads(captured.out)
    assert "cut short" in captured.err and f"{frames.size:,} objects" in captured.err
    assert result["damage"] and result["frames"]["received"] < frames.size


def _pdo_garbage(periods: int, seed: int = 2) -> list:
    """SYNC and random payloads on the three PDO IDs of the CiA 402 drive, every period."""
    import can
    import numpy as np

    rng = np.random.default_rng(seed)
    out = []
    for k in range(periods):
        t = k * 0.01
        out.append(can.Message(timestamp=t, arbitration_id=0x080, dlc=0, is_extended_id=False))
        for j, fid in enumerate((0x181, 0x281, 0x201)):
            out.append(can.Message(timestamp=t + 1e-4 * (j + 1), arbitration_id=fid,
                                   data=bytes(rng.integers(0, 256, 6).tolist()),
                                   is_extended_id=False))
    return out


def test_random_pdo_payloads_are_implausible_not_faults(tmp_path, capsys):
    """CANopen PDOs carry no CRC: random payloads on the drive's PDO IDs are counted
    "implausible" by the shipped config's physical ranges and raise no fault."""
    import json

    import can

    log = tmp_path / "garbage.asc"
    with can.Logger(str(log)) as writer:
        for message in _pdo_garbage(6000):
            writer.on_message_received(message)
    cia402 = REPO / "deploy" / "config" / "dc_motor_cia402.yaml"
    assert main(["replay", str(log), "--config", str(cia402), "--json", "--no-progress"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["faults"] == [] and result["unexplained"] == []
    implausible = result["frames"]["invalid_by_reason"]["implausible"]
    assert implausible >= 0.9 * 3 * 6000


def test_a_duplicated_chunk_is_read_once_and_said(tmp_path, capsys):
    import json

    from canfdi.io.scan import OP_CHUNK, McapFile

    log = tmp_path / "run.mcap"
    assert main(["demo", "--scenario", "dc_motor_actuator", "-o", str(log), "--no-live",
                 "--json"]) == 0
    capsys.readouterr()
    with McapFile(log) as f:
        chunks = [(start - 9, stop) for op, start, stop, _ in f.records(inflate=False)
                  if op == OP_CHUNK]
    data = log.read_bytes()
    a, b = chunks[0]
    copy = tmp_path / "copy.mcap"
    copy.write_bytes(data[:b] + data[a:b] + data[b:])
    runs = []
    for path in (log, copy):
        assert main(["replay", str(path), "--config", str(CONFIG), "--json",
                     "--no-progress"]) == 0
        captured = capsys.readouterr()
        runs.append((json.loads(captured.out), captured.err))
    (clean, _), (copied, err) = runs
    assert copied["frames"]["received"] == clean["frames"]["received"]
    assert copied["samples"] == clean["samples"] and len(copied["faults"]) == 1
    assert "a copy of the chunk" in err and copied["damage"]
    # fleet's logs table carries the loss too (its byte counts cannot: nothing was lost).
    from canfdi.tools.fleet import LogTask, diagnose_log

    row = diagnose_log(LogTask(str(copy), "copy.mcap", "d1", str(CONFIG))).log
    assert "a copy of the chunk" in row["damage"] and row["samples"] == clean["samples"]


def test_swapped_and_foreign_chunks_are_read_in_log_order_and_skipped(tmp_path, capsys):
    """Two chunks of frames far apart swapped (with the summary, and cut before it), and a
    chunk of another recording inserted: replay diagnoses what the intact log gives."""
    import json

    from tests.integration.test_damaged_logs import make_log, reference

    log = reference(make_log(tmp_path / "a.mcap", "dc_motor_consecutive", 25.0, faults=True))
    other = reference(make_log(tmp_path / "b.mcap", "dc_motor_nominal", 12.0, faults=False))
    data = log.data
    (a, b), (c, d) = log.region(2), log.region(len(log.chunks) - 4)
    swapped = data[:a] + data[c:d] + data[b:c] + data[a:b] + data[d:]
    x, y = other.region(5)
    copies = {"swapped": swapped, "swapped, no summary": swapped[: log.summary_start - 13],
              "inserted": data[:b] + other.data[x:y] + data[b:]}
    runs = {}
    for name, content in [("intact", data), *copies.items()]:
        path = tmp_path / "copy.mcap"
        path.write_bytes(content)
        assert main(["replay", str(path), "--config", str(CONFIG), "--json",
                     "--no-progress"]) == 0
        captured = capsys.readouterr()
        runs[name] = (json.loads(captured.out), captured.err)
    intact = runs["intact"][0]
    assert len(intact["faults"]) == 2
    for name in copies:
        result = runs[name][0]
        assert result["frames"] == intact["frames"], name
        assert result["samples"] == intact["samples"], name
        assert [f["onset_sample"] for f in result["faults"]] == \
            [f["onset_sample"] for f in intact["faults"]], name
        assert result["unexplained"] == [], name
    assert "chunks out of log-time order, read in the order the summary lists" \
        in runs["swapped"][1]
    assert "in the order of their messages' times" in runs["swapped, no summary"][1]
    assert "that the summary does not list (not this recording's), skipped" \
        in runs["inserted"][1]
