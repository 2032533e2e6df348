"""The library behind `canfdi identify`: the output_error method's OE models (seed 003) fitted
from a fault-free log.

`log_samples` assembles a log's samples with the config's DBC (any format canfdi.io reads; a
damaged MCAP around its damage, recorded in the `Damage` given);
`identify` fits y = y0 + sum_i B_i(q)/F_i(q) q^-d (u_c,i - u0) for every output by the OE
prediction-error method (canfdi.methods.output_error.model: Steiglitz-McBride start, then
Levenberg-Marquardt on the simulation error), drops the paths the data cannot tell from none,
and raises an order where the information criterion asks for it.
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
from canfdi.methods.output_error.model import OeModel, fit_miso, long_run_ratio

__all__ = ["assembled_samples", "identify", "log_samples", "regular_grid"]


def log_samples(path: Path, config: MonitorConfig, damage: Damage | None = None) -> tuple:
    """(k, U, Z) of a log's first drive, assembled from its frames with the config's DBC, map
    and sample clock; what a damaged log lost is recorded in ``damage``."""
    return assembled_samples(frame_blocks(path, damage=damage), config)


def assembled_samples(blocks: Iterable[FrameBlock], config: MonitorConfig) -> tuple:
    """(k (N,), U (N, p), Z (N, q)) of the config's first drive from blocks of frames, in
    order (U, Z None when no sample formed)."""
    asm = make_clock(BusMap.from_config(config), config.model.dt or 1.0, config.bus.clock)
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


def regular_grid(k: np.ndarray, U: np.ndarray, Z: np.ndarray) -> tuple:
    """Samples on a regular grid k0..k1: missing samples as NaN rows, lost commands held
    (returns U held, Z with NaN, valid (N,) per output mask)."""
    n = int(k[-1] - k[0] + 1)
    Ug = np.full((n, U.shape[1]), np.nan)
    Zg = np.full((n, Z.shape[1]), np.nan)
    Ug[k - k[0]] = U
    Zg[k - k[0]] = Z
    for i in range(Ug.shape[1]):
        col = Ug[:, i]
        idx = np.where(~np.isnan(col), np.arange(n), 0)
        np.maximum.accumulate(idx, out=idx)
        Ug[:, i] = col[idx]
        first = np.flatnonzero(~np.isnan(col))
        Ug[: first[0] if len(first) else n, i] = np.nanmean(col) if len(first) else 0.0
    return Ug, Zg


def identify(k, U, Z, inputs, outputs, fixed: dict, delay: int, min_snr: float, skip: int,
             progress=None) -> dict:
    """Fit every output; returns {"model", "sigma", "long_run", "fits": per output report}."""
    Ug, Zg = regular_grid(k, U, Z)
    u0 = Ug.mean(axis=0)
    pairs, sigma, long_run, report = [], [], [], []
    for j, name in enumerate(outputs):
        if progress:
            progress(f"fitting {name} ({j + 1} of {len(outputs)})")
        valid = ~np.isnan(Zg[:, j])
        y0 = float(np.mean(Zg[valid, j]))
        y = np.where(valid, Zg[:, j] - y0, 0.0)

        def fit(struct, y=y, valid=valid, j=j):
            return fit_miso(Ug - u0, y, struct, output=j, skip=skip, valid=valid)

        free = [i for i in range(len(inputs)) if (j, i) not in fixed]
        orders = {i: (1, 1, delay) for i in free}
        orders.update({i: fixed[(j, i)] for i in range(len(inputs))
                       if fixed.get((j, i)) is not None})

        def struct_of(orders):
            return [(i, *orders[i]) for i in sorted(orders)]

        result = fit(struct_of(orders)) if orders else None
        if result is not None and free:
            # Drop the pairs the data cannot tell from no path.
            weak = [p.input for p, g in zip(result.pairs, result.gain_std, strict=True)
                    if p.input in free and abs(p.static_gain) < min_snr * g]
            for i in weak:
                del orders[i]
            if weak:
                result = fit(struct_of(orders)) if orders else None
            # Raise an order where the information criterion says the data want it.
            n_used = int(valid[skip:].sum())

            def bic(res, orders, n_used=n_used):
                n_par = sum(nb + nf for nb, nf, _ in orders.values()) + 1
                return n_used * np.log(res.sigma**2) + n_par * np.log(n_used)

            for i in [i for i in free if i in orders]:
                trial = dict(orders)
                trial[i] = (2, 2, orders[i][2])
                res2 = fit(struct_of(trial))
                if bic(res2, trial) < bic(result, orders) - 10.0:
                    orders, result = trial, res2
        if result is None:
            r = y
            fitted, gain_std, offset = (), [], 0.0
        else:
            r, fitted, gain_std, offset = (result.residual, result.pairs, result.gain_std,
                                           result.offset)
        rv = r[skip:][valid[skip:]]
        sigma.append(float(np.std(rv)))
        long_run.append(long_run_ratio(rv))
        pairs.extend(fitted)
        report.append({
            "output": name, "residual_std": sigma[-1], "long_run_variance": long_run[-1],
            "pairs": [{"input": inputs[p.input], "b": list(p.b), "f": list(p.f),
                       "delay": p.delay, "static_gain": p.static_gain, "gain_std": float(g)}
                      for p, g in zip(fitted, gain_std, strict=True)],
            "y0": y0 + offset,
        })
    y0 = np.array([rep["y0"] for rep in report])
    model = OeModel(pairs=tuple(pairs), u0=u0, y0=y0)
    return {"model": model, "sigma": np.array(sigma), "long_run": np.array(long_run),
            "fits": report, "samples": len(Ug)}
