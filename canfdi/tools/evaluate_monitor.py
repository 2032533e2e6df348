"""Which monitor `canfdi evaluate` evaluates, on which drive: the config's own, another config's
monitor on the drive the config describes (--faults-from), or the config calibrated first on
the healthy drive (--calibrate), as a user would deploy it."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from canfdi.core.settings import ConfigError, MonitorConfig

if TYPE_CHECKING:
    from canfdi.tools.calibrate import Calibration

__all__ = ["CALIBRATION_SEED_OFFSET", "EvaluatedMonitor", "SignalsDiffer", "calibrated",
           "evaluated_monitor"]

CALIBRATION_SEED_OFFSET = 10**6
"""The healthy run a monitor is calibrated on is seeded with the evaluation's seed plus this:
its noise is none of the evaluated runs'."""


class SignalsDiffer(Exception):
    """The config the faults are drawn from does not have the monitored config's signals.

    Examples
    --------
    >>> str(SignalsDiffer("inputs"))
    'inputs'
    """


@dataclass(frozen=True)
class EvaluatedMonitor:
    """What canfdi.tools.evaluate.evaluate takes: ``drawn``, the config whose design gives the
    faults, their sizes and the drive's noise; ``monitor``, the config monitored when another
    one (None: ``drawn``'s own); ``calibration``, the calibration ``monitor`` came from (None
    without one).

    Examples
    --------
    >>> from canfdi.config import load_config
    >>> from canfdi.configs import CONFIG_DIR
    >>> config = load_config(CONFIG_DIR / "dc_motor.yaml")
    >>> chosen = evaluated_monitor(config, "dc_motor")
    >>> chosen.drawn is config, chosen.monitor, chosen.calibration
    (True, None, None)
    """

    drawn: MonitorConfig
    monitor: MonitorConfig | None = None
    calibration: Calibration | None = None


def calibrated(config: MonitorConfig, plant: str, noise_scale: float, seconds: float,
               seed: int, progress: Callable[[str], None]) -> Calibration:
    """`canfdi calibrate` on ``seconds`` of the plant, healthy, at ``noise_scale`` times the
    config's noise (its own seed), through the config's bus: the monitor a user would deploy
    on that drive.

    Raises
    ------
    ValueError
        The healthy run cannot calibrate the config (too few samples, a detection in it).
    """
    import numpy as np

    from canfdi.config import read_yaml
    from canfdi.firmware_sim.plants import make_plant
    from canfdi.firmware_sim.scenario import parse_scenario
    from canfdi.tools.calibrate import calibrate_records, scenario_records

    std = config.design.measurement_std
    if std is None:
        std = make_plant(plant).noise_defaults().measurement
    progress(f"calibrating on {seconds:g} s of the healthy drive at {noise_scale:g}x noise")
    healthy_seed = seed + CALIBRATION_SEED_OFFSET
    healthy = parse_scenario({"plant": plant, "duration": seconds, "seed": healthy_seed,
                              "noise": {"measurement": [float(v) for v in
                                                        np.asarray(std) * noise_scale]}})
    return calibrate_records(scenario_records(config, healthy, seconds, healthy_seed), config,
                             read_yaml(config.path, ConfigError, "config"))


def evaluated_monitor(config: MonitorConfig, plant: str, *,
                      faults_from: MonitorConfig | None = None,
                      calibrate_seconds: float | None = None, noise_scale: float = 1.0,
                      seed: int = 1, progress: Callable[[str], None] = lambda _: None
                      ) -> EvaluatedMonitor:
    """The configs of an evaluation of ``config`` on the emulated ``plant``.

    Parameters
    ----------
    config : the monitor config evaluated.
    plant : the emulated plant's name.
    faults_from : a config with ``config``'s signals whose design (the drive's true model)
        draws the faults and the noise; ``config`` is then the one monitored.
    calibrate_seconds : calibrate the drawn config first on this many seconds of the healthy
        drive (`calibrated`) and monitor the result.
    noise_scale, seed : the evaluation's (the calibration's drive noise, its seed).
    progress : one line per step.

    Raises
    ------
    SignalsDiffer
        ``faults_from``'s inputs or outputs are not ``config``'s.
    ValueError
        The calibration failed (as `calibrated`).
    """
    drawn, monitor, calibration = config, None, None
    if faults_from is not None:
        if (faults_from.inputs, faults_from.outputs) != (config.inputs, config.outputs):
            raise SignalsDiffer(f"inputs {faults_from.inputs}, outputs {faults_from.outputs}")
        drawn, monitor = faults_from, config
    if calibrate_seconds is not None:
        calibration = calibrated(drawn, plant, noise_scale, calibrate_seconds, seed, progress)
        monitor = calibration.config
    return EvaluatedMonitor(drawn, monitor, calibration)
