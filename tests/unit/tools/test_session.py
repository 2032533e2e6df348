"""canfdi.tools.session, the one builder of run's, demo's and capture's sessions: run's
recording (file name, rotation, retention), teach-in too short to learn from, the stop event
and the counters a served session reports."""

from __future__ import annotations

import dataclasses
import logging
import signal
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from canfdi.config import load_config
from canfdi.core.settings import RecordingConfig
from canfdi.tools.session import (
    Recording,
    Session,
    SessionError,
    StopEvent,
    open_session,
    run_recording,
)
from tests.conftest import REPO

CONFIG = REPO / "deploy" / "config" / "dc_motor.yaml"
LOG = logging.getLogger("canfdi.test")


def _config(**recording):
    config = load_config(CONFIG)
    return dataclasses.replace(config, recording=RecordingConfig(**recording))


def test_run_records_to_a_file_named_after_the_config_and_rotates_by_the_config(tmp_path):
    rec = run_recording(_config(directory=str(tmp_path / "logs"), rotate_mib=2,
                                rotate_minutes=0.5), None, None, LOG)
    assert rec.path.parent == tmp_path / "logs"
    assert rec.path.name.startswith("dc_motor-") and rec.path.suffix == ".mcap"
    assert (rec.rotate_bytes, rec.rotate_seconds, rec.log_lines) == (2 * 2**20, 30.0, True)
    assert rec.prune is None  # no keep_days, no keep_mib: nothing is removed
    assert run_recording(_config(), None, tmp_path, LOG).path.parent == tmp_path  # --log-dir


def test_only_files_run_names_itself_are_pruned(tmp_path):
    old = tmp_path / "dc_motor-20000101-000000.mcap"
    old.write_bytes(b"x" * 100)
    named = run_recording(_config(directory=str(tmp_path), keep_mib=0), None, None, LOG)
    assert named.prune is not None
    named.prune(())
    assert not old.exists()
    given = run_recording(_config(directory=str(tmp_path), keep_days=1), tmp_path / "x.mcap",
                          None, LOG)
    assert given.path == tmp_path / "x.mcap" and given.prune is None  # -o: never pruned


def test_a_teach_in_too_short_is_a_session_error_before_anything_opens():
    with pytest.raises(SessionError, match=r"--teach: 0.01 s is 1 samples") as caught:
        open_session(load_config(CONFIG), "run", teach=0.01, foxglove="not an address")
    assert caught.value.status == 2


def test_sigint_stops_with_130_and_sigterm_with_0():
    stop = StopEvent()
    stop._signalled(signal.SIGTERM)
    assert stop.is_set() and stop.exit_status == 0
    stop._signalled(signal.SIGINT)
    assert stop.exit_status == 130


class _Monitor:
    sink = None
    last_timestamp_ns = None

    def summary(self):
        return {"faults": [{"kind": "sensor"}]}


class _Recorder:
    def __init__(self) -> None:
        self.paths = [Path("run.mcap")]
        self.messages_written, self.messages_dropped, self.write_errors = 10, 1, 1
        self.last_error = OSError(28, "full")
        self.closed = False

    def close(self):
        self.closed = True


def test_a_served_session_reports_its_counters_and_closes_what_it_opened():
    recorder, server = _Recorder(), SimpleNamespace(lagging=2, oversize=3, closed=False)
    server.close = lambda: setattr(server, "closed", True)
    session = Session(_Monitor(), recorder=recorder, foxglove=server)
    session.recording = Recording(Path("run.mcap"))
    assert session.monitor.sink is recorder
    assert session.drive_time() > 0  # no frame yet: the wall clock
    with session:
        pass
    assert recorder.closed and server.closed
    stats = SimpleNamespace(frames=5, sent=4, bus_errors=1, bus_down_s=0.12345, gave_up=False)
    assert session.stopped(stats) == {
        "frames": 5, "sent": 4, "bus_errors": 1, "bus_down_s": 0.123, "faults": 1,
        "gave_up": False, "foxglove": {"lagging": 2, "oversize": 3},
        "recording": {"segments": ["run.mcap"], "written": 10, "dropped": 1,
                      "write_errors": 1, "last_error": "full"}}
    session.recording = Recording(None)  # a tap for Foxglove only: no recording counts
    assert "recording" not in session.stopped(stats)


def test_a_discarded_recording_leaves_no_file(tmp_path):
    recorder = _Recorder()
    recorder.paths = [tmp_path / "c.mcap", tmp_path / "c-0001.mcap"]
    for path in recorder.paths:
        path.write_bytes(b"")
    Session(_Monitor(), recorder=recorder).discard_recording()
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("encoding", ["json", "cdr", None])
def test_the_recorder_writes_rows_in_the_configs_row_encoding(tmp_path: Path, encoding) -> None:
    """recording.row_encoding picks the rows' encoding (None: the recorder's default, CDR)."""
    from mcap.reader import make_reader

    from canfdi.core.records import Sample
    from canfdi.tools.session import close_recorder, open_recorder

    path = tmp_path / "run.mcap"
    recorder = open_recorder(path, recording=RecordingConfig(row_encoding=encoding))
    recorder.write_sample(Sample(k=0, timestamp_ns=5, u=np.array([1.0]), z=np.array([2.0]),
                                 gap=0), ["v"], ["w"])
    close_recorder(recorder)
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None
    (channel,) = summary.channels.values()
    assert channel.message_encoding == ("json" if encoding == "json" else "cdr")
