"""airspeed velocity (asv) benchmarks of the monitor's hot paths, as numpy and scipy track
theirs across commits: `asv continuous main HEAD` times both commits side by side and names
what got slower; `asv run --python=same --quick` times the working tree in this environment.

Each benchmark that a kernel runs is parametrised by the kernels this install built
(canfdi.core.kernel), so the C kernel and the numpy reference are timed side by side. The
data are the DC motor on canfdi's own bus, the shipped config, as `canfdi bench` uses them.
"""

from __future__ import annotations

import numpy as np
from canfdi.configs import CONFIG_DIR

from canfdi.config import load_config
from canfdi.core import kernel as kernels
from canfdi.core.detect import ChangePointDetector
from canfdi.core.residuals import ResidualBank
from canfdi.methods import build_diagnoser
from canfdi.monitor import Monitor
from canfdi.tools.bench import make_traffic

CONFIG = CONFIG_DIR / "dc_motor.yaml"
KERNELS = tuple(kernels.available())
FRAMES = 100_000  # frames of the bus benchmarks
SAMPLES = 50_000  # rows of the residual and detector benchmarks


def _traffic(frames: int, scenario: str):
    return make_traffic(frames, scenario)


class Decode:
    """The drive's frames checked and decoded to values (BusMap.decode_frames), FRAMES
    frames."""

    timeout = 120
    params = KERNELS
    param_names = ("kernel",)

    def setup(self, kernel: str) -> None:
        self.monitor = Monitor(load_config(CONFIG), diagnose=False, kernel=kernels.get(kernel))
        self.bus_map = self.monitor.drives[0].bus_map
        self.traffic = _traffic(FRAMES, "dc_motor_nominal")

    def time_decode_frames(self, kernel: str) -> None:
        self.bus_map.decode_frames(self.traffic)


class Residuals:
    """The residual bank's block form over SAMPLES samples, lost values included."""

    params = KERNELS
    param_names = ("kernel",)

    def setup(self, kernel: str) -> None:
        diagnoser = kernels.get(kernel).use_on(build_diagnoser(load_config(CONFIG)))
        self.bank: ResidualBank = diagnoser.bank
        rng = np.random.default_rng(0)
        self.x = rng.standard_normal((SAMPLES, self.bank.q + self.bank.p))
        self.x[rng.random(self.x.shape) < 0.001] = np.nan

    def time_batch(self, kernel: str) -> None:
        self.bank.batch(self.x)


class Detectors:
    """Page-Hinkley over SAMPLES rows of 6 residuals, no alarm (the monitoring path)."""

    params = KERNELS
    param_names = ("kernel",)

    def setup(self, kernel: str) -> None:
        self.detector = ChangePointDetector(6, 0.5, np.full(6, 1e6))
        kernels.get(kernel).install(detectors=(self.detector,))
        rng = np.random.default_rng(1)
        self.rn = rng.standard_normal((SAMPLES, 6))
        self.k = np.arange(SAMPLES)

    def time_update_block(self, kernel: str) -> None:
        self.detector.reset()
        self.detector.update_block(self.k, self.rn)


class Monitoring:
    """Decode, assemble, residuals, detectors: Monitor.on_frames over FRAMES frames of the
    fault-free drive (no recording), and of the drive with its three consecutive faults
    (diagnoses included)."""

    params = (KERNELS, ("dc_motor_nominal", "dc_motor_consecutive"))
    param_names = ("kernel", "scenario")
    timeout = 300

    def setup(self, kernel: str, scenario: str) -> None:
        self.config = load_config(CONFIG)
        self.traffic = _traffic(FRAMES, scenario)
        self.kernel = kernels.get(kernel)
        Monitor(self.config, kernel=self.kernel)  # the design and thresholds, memoised

    def time_on_frames(self, kernel: str, scenario: str) -> None:
        monitor = Monitor(self.config, record_residuals=False, kernel=self.kernel)
        for i in range(0, self.traffic.size, 4096):
            monitor.on_frames(self.traffic.slice(i, i + 4096))
        monitor.finish()
