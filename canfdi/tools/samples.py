"""A log's samples: its frames decoded and assembled with a config's bus, on a regular grid.

The verbs that learn from logs (identify, calibrate) read them this way: `log_samples` (any
format canfdi.io reads; a damaged MCAP around its damage, recorded in the `Damage` given),
`assembled_samples` (blocks of frames already read); `canfdi.core.sysid.regular_grid` puts
them on their grid.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from canfdi.bus.clock import make_clock
from canfdi.bus.dbc import BusMap
from canfdi.bus.frames import FrameBlock
from canfdi.core.settings import MonitorConfig
from canfdi.io.damage import Damage
from canfdi.io.logs import frame_blocks

__all__ = ["assembled_samples", "log_samples", "sample_period"]


def sample_period(config: MonitorConfig) -> float | None:
    """The config's sample period: the model's dt, the clock's period (a model still to be
    identified has no dt of its own), or None."""
    if config.model is not None and config.model.dt:
        return float(config.model.dt)
    return config.dt


def log_samples(path: Path, config: MonitorConfig, damage: Damage | None = None,
                dt: float | None = None) -> tuple:
    """(k, U, Z) of a log's first drive, assembled from its frames with the config's DBC, map
    and sample clock (period ``dt``, default the config's); what a damaged log lost is
    recorded in ``damage``."""
    return assembled_samples(frame_blocks(path, damage=damage), config, dt)


def assembled_samples(blocks: Iterable[FrameBlock], config: MonitorConfig,
                      dt: float | None = None) -> tuple:
    """(k (N,), U (N, p), Z (N, q)) of the config's first drive from blocks of frames, in
    order (U, Z None when no sample formed); ``dt`` the sample period (default the
    config's)."""
    period = dt or sample_period(config) or 1.0
    asm = make_clock(BusMap.from_config(config), period, config.bus.clock)
    ks, us, zs = [], [], []
    for block in blocks:
        log = asm.push_batch(block)
        ks.append(log.k)
        us.append(log.u)
        zs.append(log.z)
    for s in asm.flush():
        ks.append(np.array([s.k]))
        us.append(np.asarray(s.u)[None, :])
        zs.append(np.asarray(s.z)[None, :])
    if not ks:
        return np.zeros(0, dtype=np.int64), None, None
    return np.concatenate(ks), np.vstack(us), np.vstack(zs)
