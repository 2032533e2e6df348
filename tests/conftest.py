"""Shared pytest configuration: the `vcan` marker skips where there is no vcan0, the `c` marker
where the C kernel (canfdi._ckernel) was not built."""

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


def _has_c_kernel() -> bool:
    from canfdi.core import kernel

    return "c" in kernel.available()


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    skips = {}
    if not _has_vcan0():
        skips["vcan"] = pytest.mark.skip(
            reason="no vcan0 on this host (kernel without SocketCAN); run through "
                   "deploy/vcan-harness")
    if not _has_c_kernel():
        skips["c"] = pytest.mark.skip(
            reason="the C kernel was not built (no C compiler at install): pip install -e . "
                   "with gcc or clang on the PATH")
    for item in items:
        for marker, skip in skips.items():
            if marker in item.keywords:
                item.add_marker(skip)


def feed_frame_log(monitor, log, block: int = 4096):
    """A scenario's frames (canfdi.firmware_sim.emitter.frame_log) through ``monitor`` in blocks, as
    a live service hands them over, then end of stream. Returns the monitor."""
    for i in range(0, log.frames.size, block):
        monitor.on_frames(log.frames.slice(i, i + block))
    monitor.finish()
    return monitor


def events_by_chunking(config, k, U, Z, blocks=(1, 333, 4096)) -> list[list[tuple]]:
    """The events of a fresh monitor of ``config`` over the same samples (k (N,), U (N, p), Z
    (N, q), 10 ms apart) fed one at a time (a block of 1: ``on_sample``) and in blocks of each
    other size (``on_samples``): per block size, (kind, sample, name, estimates rounded to 9
    digits: sums in another order are rounding apart) of each event."""
    import numpy as np

    from canfdi.core.records import Sample
    from canfdi.monitor import Monitor

    out = []
    for block in blocks:
        monitor = Monitor(config, record_residuals=False)
        if block == 1:
            for i in range(len(k)):
                monitor.on_sample(Sample(int(k[i]), int(k[i]) * 10**7, U[i], Z[i]))
        else:
            for i in range(0, len(k), block):
                s = slice(i, i + block)
                monitor.on_samples(k[s], k[s] * 10**7, U[s], Z[s],
                                   np.zeros(len(k[s]), dtype=np.int64))
        out.append([(e.kind, e.sample, e.name, tuple((n, round(v, 9))
                                                     for n, v in sorted(e.estimates.items())))
                    for e in monitor.events])
    return out
