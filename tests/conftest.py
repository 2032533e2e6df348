"""Shared pytest configuration: the `vcan` marker skips where there is no vcan0."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import pytest

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# `canfdi run` keeps its designs in a cache directory (canfdi.io.memostore): the tests' runs,
# in this process and the ones it starts, keep theirs in one of their own, not the user's.
os.environ.setdefault("CANFDI_CACHE_DIR", tempfile.mkdtemp(prefix="canfdi-test-cache-"))

REPO = Path(__file__).resolve().parent.parent


def _has_vcan0() -> bool:
    return Path("/sys/class/net/vcan0").exists()


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if _has_vcan0():
        return
    skip = pytest.mark.skip(
        reason="no vcan0 on this host (kernel without SocketCAN); run through deploy/vcan-harness"
    )
    for item in items:
        if "vcan" in item.keywords:
            item.add_marker(skip)


def feed_frame_log(monitor, log, block: int = 4096):
    """A scenario's frames (canfdi.firmware_sim.emitter.frame_log) through ``monitor`` in blocks, as
    a live service hands them over, then end of stream. Returns the monitor."""
    for i in range(0, log.frames.size, block):
        monitor.on_frames(log.frames.slice(i, i + block))
    monitor.finish()
    return monitor
