"""A silent bus is a state a supervisor sees, and the bus passes only the drives' frames.

The service on python-can's virtual bus: the DC motor's frames, then silence, then frames
again; FDI_STATUS as cantools decodes it with the shipped canfdi_monitor.dbc says
"no_traffic" in between, systemd's STATUS= lines say so, and frames of foreign IDs are not
traffic. The receive filters of every shipped profile pass exactly the IDs its bus map reads.
"""

import asyncio
import itertools

import can
import cantools
import pytest
from canfdi.configs import CONFIG_DIR
from canfdi.dbc import DBC_DIR

from canfdi.config import load_config
from canfdi.monitor import Monitor
from canfdi.service import MonitorService, open_bus
from canfdi.tools.bench import make_traffic

CONFIG = CONFIG_DIR / "dc_motor.yaml"
_channels = itertools.count()


def messages(block):
    return [can.Message(arbitration_id=i, data=d, is_extended_id=False)
            for i, d in zip(block.id.tolist(), block.payloads(), strict=True)]


def run_service(monitor, script, no_traffic=0.3):
    """Run the service on a fresh virtual channel while ``script(sender)`` sends; returns
    (FDI_STATUS states decoded by cantools, STATUS= lines, log records' messages)."""
    channel = f"canfdi-traffic-{next(_channels)}"
    database = cantools.database.load_file(DBC_DIR / "canfdi_monitor.dbc")
    status_id = monitor.frames.keys["FDI_STATUS"][0]
    said: list[str] = []

    async def main():
        sender = can.Bus(interface="virtual", channel=channel)
        listener = can.Bus(interface="virtual", channel=channel)
        stop = asyncio.Event()
        service = MonitorService(
            monitor, lambda: open_bus("virtual", channel), status_period=0.05,
            no_traffic=no_traffic, on_status=said.append)
        task = asyncio.create_task(service.run(stop))
        while service.bus is None:
            await asyncio.sleep(0.01)
        await script(sender)
        stop.set()
        await task
        states = []
        while (msg := listener.recv(0)) is not None:
            if msg.arbitration_id == status_id:
                state = database.decode_message(status_id, msg.data)["State"]
                if not states or states[-1] != str(state):
                    states.append(str(state))
        sender.shutdown()
        listener.shutdown()
        return states

    return asyncio.run(main()), said


async def send(sender, frames):
    for msg in frames:
        sender.send(msg)
        await asyncio.sleep(0.001)


def test_silence_is_said_on_fdi_status_and_to_systemd_and_resuming_too(caplog):
    monitor = Monitor(load_config(CONFIG))
    frames = messages(make_traffic(300))

    async def script(sender):
        await send(sender, frames[:150])
        await asyncio.sleep(0.8)  # silent for longer than no_traffic
        await send(sender, frames[150:])
        await asyncio.sleep(0.2)

    with caplog.at_level("INFO", logger="canfdi.service"):
        states, said = run_service(monitor, script)
    # (100 samples: the monitor is still checking the configured noise on its first ones.)
    assert states == ["checking", "no_traffic", "checking"]
    assert said[0] == "monitoring" and said[1].startswith("no traffic for ")
    assert said[2] == "monitoring"
    lines = [r.getMessage() for r in caplog.records]
    assert any(line.startswith("receiving the drives' frames") for line in lines)
    assert any(line.startswith("no traffic: no frame of the drives for") for line in lines)
    assert any(line.startswith("traffic resumed after") for line in lines)


def test_a_bus_that_never_carries_the_drives_frames_is_silent_even_with_foreign_ones():
    monitor = Monitor(load_config(CONFIG))
    foreign = [can.Message(arbitration_id=0x700 + i % 8, data=bytes(8), is_extended_id=False)
               for i in range(200)]

    async def script(sender):
        await send(sender, foreign)
        await asyncio.sleep(0.4)

    states, said = run_service(monitor, script)
    assert states == ["checking", "no_traffic"]
    assert said and said[0].startswith("no traffic for ")
    assert monitor.mapped_frames == 0 and monitor.frame_stats["frames_received"] == 200


def test_no_traffic_zero_never_says_silent():
    monitor = Monitor(load_config(CONFIG))

    async def script(sender):
        await asyncio.sleep(0.5)

    states, said = run_service(monitor, script, no_traffic=0)
    assert "no_traffic" not in states and said == []


@pytest.mark.parametrize("name", ["dc_motor", "dc_motor_cia402", "dc_motor_two_drives_cia402",
                                  "dc_motor_float", "vtol", "winding_machine"])
def test_receive_filters_pass_exactly_the_ids_the_bus_map_reads(name):
    monitor = Monitor(load_config(CONFIG_DIR / f"{name}.yaml"))
    wanted = {key for drive in monitor.drives for key in drive.bus_map.keys}
    filters = monitor.receive_filters()
    assert {(f["can_id"], f["extended"]) for f in filters} == wanted
    # python-can applies them (in software on the virtual bus, in the kernel on SocketCAN).
    channel = f"canfdi-filters-{name}"
    with can.Bus(interface="virtual", channel=channel) as sender, \
            open_bus("virtual", channel, can_filters=filters) as receiver:
        ids = sorted({fid for fid, _ in wanted} | {0x7F0, 0x123, 0x6A0})
        for fid in ids:
            sender.send(can.Message(arbitration_id=fid, data=bytes(8), is_extended_id=False))
            sender.send(can.Message(arbitration_id=fid, data=bytes(8), is_extended_id=True))
        got = set()
        while (msg := receiver.recv(0.05)) is not None:
            got.add((msg.arbitration_id, msg.is_extended_id))
    assert got == wanted
