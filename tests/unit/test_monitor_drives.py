"""Several drives on one bus: each frame to the drives that map it, streaming == blocks; each
drive its own diagnoser, run by its own supervisor (canfdi.core.protocol.Supervisor)."""

import dataclasses

import numpy as np
import pytest

from canfdi.config import ConfigError, load_config
from canfdi.core.protocol import Supervisor
from canfdi.firmware_sim.emitter import frame_log
from canfdi.firmware_sim.scenario import load_scenario
from canfdi.monitor import Monitor
from tests.conftest import REPO

CONFIG = REPO / "deploy" / "config" / "dc_motor_two_drives_cia402.yaml"


@pytest.fixture(scope="module")
def two_drives():
    return frame_log(load_scenario("dc_motor_two_drives_cia402"), duration=14.0)


def _events(monitor):
    return [(e.drive, e.kind, e.target, e.index, e.sample, e.onset_sample) for e in
            monitor.events]


def test_frame_by_frame_and_by_blocks_give_the_same_diagnoses_and_counters(two_drives):
    frames = two_drives.frames
    streamed = Monitor(load_config(CONFIG))
    for msg in frames.to_messages():
        streamed.on_frame(round(msg.timestamp * 1e9), msg.arbitration_id, bytes(msg.data),
                          is_remote=msg.is_remote_frame)
    blocks = Monitor(load_config(CONFIG))
    for start in range(0, frames.size, 1000):
        blocks.on_frames(frames.slice(start, min(start + 1000, frames.size)))
    assert _events(streamed) == _events(blocks)
    assert [e[0] for e in _events(blocks) if e[1] == "accepted"] == ["left"]
    assert streamed.frame_stats == blocks.frame_stats
    assert blocks.frame_stats["frames_received"] == frames.size  # the shared SYNC once
    assert [d.samples for d in blocks.drives] == [d.samples for d in streamed.drives] == [
        1399, 1399]


def test_the_shared_sync_triggers_both_drives_and_a_node_template_alone_would_not(two_drives):
    config = load_config(CONFIG)
    unshared = dataclasses.replace(config, bus=dataclasses.replace(config.bus, node_shared=()))
    monitor = Monitor(unshared)
    monitor.on_frames(two_drives.frames)
    # Without shared, SYNC moves with the template (0x081, 0x082): no drive hears a trigger,
    # and 0x080 is only a message of the DBC (as written), known and unused.
    assert [d.samples for d in monitor.drives] == [0, 0]
    assert monitor.frame_stats["frames_invalid"] == 0
    assert np.count_nonzero(two_drives.frames.id == 0x080) == 1400


def test_a_shared_entry_must_name_a_message_of_the_dbc():
    config = load_config(CONFIG)
    bad = dataclasses.replace(config, bus=dataclasses.replace(config.bus, node_shared=("SYNK",)))
    with pytest.raises(ConfigError, match="did you mean SYNC") as info:
        Monitor(bad)
    assert info.value.field == "bus.node.shared[0]"


def test_each_drive_has_its_own_supervised_diagnoser_and_capture_none():
    config = load_config(CONFIG)
    monitor = Monitor(config)
    left, right = (d.diagnoser for d in monitor.drives)
    assert isinstance(left, Supervisor) and left is not right
    assert left.diagnoser is not right.diagnoser
    assert monitor.diagnoser is left.diagnoser  # the method's, for the tools that read it
    assert [d.state for d in monitor.drives] == ["checking", "checking"]
    capture = Monitor(config, diagnose=False)
    assert capture.diagnoser is None and [d.state for d in capture.drives] == [
        "monitoring", "monitoring"]
