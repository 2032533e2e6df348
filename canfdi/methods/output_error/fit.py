"""The output_error method's models (the output-error paper) fitted from fault-free samples: what
`canfdi
identify` learns for a config with ``method: output_error`` (the registry entry's
``fit_models``), and the black-box path's output-error fit of each output's paths.

`fit_output_error` fits y = y0 + sum_i B_i(q)/F_i(q) q^-d (u_c,i - u0) for every output by the
OE prediction-error method (canfdi.methods.output_error.model: Steiglitz-McBride start, then
Levenberg-Marquardt on the simulation error), drops the paths the data cannot tell from none,
and raises an order where the information criterion asks for it. `fit_section` gives the
config section of those models.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from canfdi.core.settings import MonitorConfig
from canfdi.core.sysid import regular_grid
from canfdi.methods.output_error.config import output_error_section
from canfdi.methods.output_error.diagnoser import OeSettings
from canfdi.methods.output_error.model import OeModel, fit_miso, long_run_ratio

__all__ = ["FitOptions", "fit_output_error", "fit_section"]


@dataclass(frozen=True)
class FitOptions:
    """The fit's choices (`canfdi identify --orders/--oe-delay/--min-gain-snr/--skip`): fixed
    pair orders {(output, input): (nb, nf, d) or None}, the free pairs' delay, the gain
    significance to keep a pair, samples skipped at the start.

    Examples
    --------
    >>> options = FitOptions(fixed={(0, 0): (1, 1, 1)}, skip=50)
    >>> options.delay, options.min_gain_snr, options.fixed[(0, 0)]
    (1, 5.0, (1, 1, 1))
    """

    fixed: dict = field(default_factory=dict)
    delay: int = 1
    min_gain_snr: float = 5.0
    skip: int = 200


def fit_section(k: np.ndarray, U: np.ndarray, Z: np.ndarray, config: MonitorConfig,
                options: FitOptions | None, progress: Callable[[str], None]
                ) -> tuple[dict[str, Any], dict[str, Any]]:
    """(the ``output_error:`` section, a JSON-able report) of the models fitted to the
    samples k (N,), U (N, p), Z (N, q), with the method's default decision settings."""
    result = fit_output_error(k, U, Z, config.inputs, config.outputs, options or FitOptions(),
                              progress)
    settings = {key: value for key, value in dataclasses.asdict(OeSettings()).items()
                if key not in ("drift", "false_alarm_interval")}
    section = output_error_section(result["model"], result["sigma"], result["long_run"],
                                   config.inputs, config.outputs,
                                   fit={"samples": result["samples"]}, **settings)
    report = {"path": "output error (the output-error paper)",
              "samples": {"fit": int(result["samples"])},
              "outputs": result["fits"]}
    return section, report


def fit_output_error(k, U, Z, inputs, outputs, options: FitOptions,
                     progress: Callable[[str], None] | None = None) -> dict:
    """Fit every output of the samples k (N,), U (N, p), Z (N, q); returns {"model",
    "sigma", "long_run", "fits": per output report, "samples"}."""
    fixed, delay, min_snr, skip = (options.fixed, options.delay, options.min_gain_snr,
                                   options.skip)
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
