"""Time is data, checked (issue 27): wild timestamps and clock steps on every sample clock,
offline through the monitor and live through the service on python-can's virtual bus."""

from __future__ import annotations

import asyncio
import dataclasses
import logging

import can
import numpy as np
import pytest

from canfdi.bus.frames import FrameBlock
from canfdi.config import load_config
from canfdi.firmware_sim.emitter import frame_log
from canfdi.firmware_sim.scenario import parse_scenario
from canfdi.monitor import Monitor
from canfdi.service import MonitorService
from tests.conftest import REPO

CONFIGS = {"counter": "dc_motor.yaml", "trigger": "dc_motor_cia402.yaml",
           "grid": "dc_motor_float.yaml"}
HOUR, DAY = 3600 * 10**9, 86400 * 10**9


def _frames(config_name: str, seconds: float = 20.0) -> tuple[Monitor, FrameBlock]:
    config = load_config(REPO / "deploy" / "config" / config_name)
    profile = {"dc_motor.yaml": "canfdi", "dc_motor_cia402.yaml": "cia402",
               "dc_motor_float.yaml": "float_node"}[config_name]
    scenario = parse_scenario({"plant": "dc_motor", "duration": seconds, "seed": 3,
                               "bus": {"profile": profile}})
    return Monitor(config, record_residuals=False), frame_log(scenario).frames


def _with_times(block: FrameBlock, t: np.ndarray) -> FrameBlock:
    return dataclasses.replace(block, t_ns=np.asarray(t, dtype=np.int64))


@pytest.mark.parametrize("kind", sorted(CONFIGS))
@pytest.mark.parametrize("wild", [HOUR, DAY, -HOUR, "1970"])
def test_a_frame_with_a_wild_timestamp_changes_nothing_but_a_counter(kind, wild):
    monitor, block = _frames(CONFIGS[kind])
    clean, _ = _frames(CONFIGS[kind])
    clean.on_frames(block)
    t = block.t_ns.copy()
    i = block.size // 2
    t[i] = 0 if wild == "1970" else t[i] + wild
    monitor.on_frames(_with_times(block, t))
    stats, reference = monitor.frame_stats, clean.frame_stats
    assert stats["invalid_by_reason"]["time_jump"] == 1
    assert stats["clock_steps"] == 0
    assert abs(monitor.samples - clean.samples) <= 1
    assert stats["samples_missing"] <= reference["samples_missing"] + 1


@pytest.mark.parametrize("kind", sorted(CONFIGS))
@pytest.mark.parametrize("step", [HOUR, DAY, -HOUR, "1970"])
def test_a_step_of_the_clock_costs_a_bounded_pause_and_is_said_once(kind, step):
    monitor, block = _frames(CONFIGS[kind])
    t = block.t_ns.copy()
    half = t >= t[block.size // 2]
    t[half] = (t[half] - t[half][0] + 10**6) if step == "1970" else t[half] + step
    monitor.on_frames(_with_times(block, t))
    stats = monitor.frame_stats
    assert stats["clock_steps"] == 1
    # 2,000 periods in 20 s: the step adds at most a bound's pause (the grid shows its 64
    # periods as samples without values), never the step's 360,000 (or 8.6 million) periods.
    assert 1900 <= monitor.samples <= 2000 + 64 + 2
    assert stats["samples_missing"] <= 256 + 256
    (notice,) = monitor.clock_notices()
    assert "clock stepped by" in notice and monitor.clock_notices() == []


def test_live_a_wall_clock_step_is_followed_and_logged_once(caplog):
    """canfdi's service on python-can's virtual bus, timestamps kept as sent: a stray frame an
    hour ahead, then the gateway's clock steps a day ahead (NTP). The diagnosis goes on with
    the sample count of the run, and the step is one warning."""
    monitor, block = _frames("dc_motor.yaml", seconds=6.0)
    t = block.t_ns.copy() + 1_700_000_000 * 10**9
    t[block.size // 3] += HOUR
    t[block.size // 2:] += DAY
    messages = [can.Message(timestamp=x / 1e9, arbitration_id=int(i), data=bytes(d[:n]),
                            is_extended_id=False)
                for x, i, d, n in zip(t.tolist(), block.id, block.data, block.dlc, strict=True)]
    channel = "canfdi-wild-time"

    async def main():
        stop = asyncio.Event()
        service = MonitorService(
            monitor, lambda: can.Bus(interface="virtual", channel=channel,
                                     preserve_timestamps=True, receive_own_messages=False),
            status_period=0)
        task = asyncio.create_task(service.run(stop))
        await asyncio.sleep(0.3)
        with can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as sender:
            for m in messages:
                sender.send(m)
        for _ in range(400):
            await asyncio.sleep(0.05)
            if service.stats.frames >= len(messages):
                break
        stop.set()
        return await task

    with caplog.at_level(logging.WARNING, logger="canfdi.service"):
        stats = asyncio.run(main())
    assert stats.frames == len(messages)
    frame_stats = monitor.frame_stats
    assert frame_stats["clock_steps"] == 1
    assert frame_stats["invalid_by_reason"]["time_jump"] >= 1
    assert 560 <= monitor.samples <= 602
    steps = [r.getMessage() for r in caplog.records if "clock stepped" in r.getMessage()]
    assert len(steps) == 1 and "+86400" in steps[0]
