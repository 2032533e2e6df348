"""`canfdi demo --foxglove [HOST:]PORT`: the log's channels served live over Foxglove's
WebSocket protocol (foxglove-sdk), received by a plain WebSocket client on 127.0.0.1."""

from __future__ import annotations

import asyncio
import contextlib
import json
import socket
import struct
import threading

import numpy as np
import pytest

pytest.importorskip("foxglove", reason="the foxglove extra is not installed")
websockets = pytest.importorskip("websockets", reason="websockets is not installed")

from canfdi.cli import main  # noqa: E402
from canfdi.liveserver import parse_address  # noqa: E402

SUBPROTOCOL = "foxglove.sdk.v1"  # what foxglove-sdk's server speaks


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


async def watch(port: int, done: threading.Event) -> dict:
    """Connect (retrying until the server is up), subscribe to every channel advertised and
    gather what arrives until the demo is done."""
    for _ in range(500):
        try:
            ws = await websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL])
            break
        except OSError:
            await asyncio.sleep(0.01)
    else:
        raise AssertionError("the Foxglove server never came up")
    channels: dict[int, dict] = {}
    topics_of: dict[int, str] = {}
    got: dict[str, list] = {}
    async with ws:
        info = json.loads(await ws.recv())
        assert info["op"] == "serverInfo"
        next_id = 1
        while not done.is_set() or got.get("/canfdi/log") is None:
            with contextlib.suppress(asyncio.TimeoutError):
                frame = await asyncio.wait_for(ws.recv(), 0.5)
                if isinstance(frame, str):
                    op = json.loads(frame)
                    if op["op"] == "advertise":
                        subs = []
                        for channel in op["channels"]:
                            channels[channel["id"]] = channel
                            topics_of[next_id] = channel["topic"]
                            subs.append({"id": next_id, "channelId": channel["id"]})
                            next_id += 1
                        await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                else:
                    assert frame[0] == 0x01  # message data
                    sub, log_time = struct.unpack_from("<IQ", frame, 1)
                    got.setdefault(topics_of[sub], []).append((log_time,
                                                              json.loads(frame[13:])))
            if done.is_set() and not got:
                break
    return {"channels": channels, "got": got}


def test_demo_serves_residuals_events_and_log_lines_live(capsys) -> None:
    port = free_port()
    done = threading.Event()
    seen: dict = {}

    def client() -> None:  # the demo needs the main thread (its signal handlers)
        seen.update(asyncio.run(asyncio.wait_for(watch(port, done), 120)))

    thread = threading.Thread(target=client)
    thread.start()
    try:
        status = [main(["demo", "--no-live", "--json", "--foxglove", f"127.0.0.1:{port}"])]
    finally:
        done.set()
        thread.join(120)
    assert status == [0]
    channels = {c["topic"]: c for c in seen["channels"].values()}
    assert {"/canfdi/residuals", "/canfdi/samples", "/canfdi/events", "/canfdi/log"} <= set(
        channels)
    for channel in channels.values():
        assert channel["encoding"] == "json" and channel["schemaEncoding"] == "jsonschema"
    schema = json.loads(channels["/canfdi/residuals"]["schema"])
    assert "s:i_a" in schema["properties"]["statistic"]["properties"]
    assert channels["/canfdi/log"]["schemaName"] == "foxglove.Log"
    got = seen["got"]
    rows = got["/canfdi/residuals"]
    assert len(rows) > 100
    # live messages carry the drive's time: 10 ms apart, as its samples
    times = [t for t, _ in rows]
    steps = np.diff(times).tolist()
    assert all(abs(step - 10_000_000) < 10_000 for step in steps), (min(steps), max(steps))
    assert all(m["timestamp"]["sec"] * 10**9 + m["timestamp"]["nsec"] == t for t, m in rows)
    kinds = [m["kind"] for _, m in got["/canfdi/events"]]
    assert "accepted" in kinds
    assert any("FAULT" in m["message"] for _, m in got["/canfdi/log"])
    result = json.loads(capsys.readouterr().out)
    assert len(result["faults"]) == 3


def test_a_bad_address_is_one_line_and_status_2(capsys) -> None:
    assert main(["demo", "--no-live", "--foxglove", "host:port"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["canfdi demo: --foxglove: expected [HOST:]PORT, got 'host:port'"]


@pytest.mark.parametrize("text, expected", [
    ("8765", ("127.0.0.1", 8765)),
    ("0.0.0.0:9000", ("0.0.0.0", 9000)),
    ("[::1]:9001", ("::1", 9001)),
    (":0", ("127.0.0.1", 0)),
])
def test_parse_address(text: str, expected: tuple[str, int]) -> None:
    assert parse_address(text) == expected
