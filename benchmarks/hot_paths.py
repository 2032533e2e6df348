"""airspeed velocity (asv) benchmarks of the monitor's hot paths, as numpy and scipy track
theirs across commits: `asv continuous main HEAD` times both commits side by side and names
what got slower; `asv run --python=same --quick` times the working tree in this environment.

Each benchmark that a kernel runs is parametrised by the kernels this install built
(canfdi.core.kernel), so the C kernel and the numpy reference are timed side by side. The
data are the DC motor on canfdi's own bus, the shipped config, as `canfdi bench` uses them.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from canfdi.configs import CONFIG_DIR

from canfdi.config import load_config
from canfdi.core import kernel as kernels
from canfdi.core.detect import ChangePointDetector
from canfdi.core.residuals import ResidualBank
from canfdi.io.rowencodings import ROW_ENCODINGS
from canfdi.io.writer import McapRecorder
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


class Recording:
    """The MCAP recorder alone: SAMPLES sample rows (1 input, 4 outputs) and residual rows (5
    residuals), as the monitor hands them over a block at a time, with a frame block of FRAMES
    frames, into a file, in each row encoding (canfdi.io.rowencodings)."""

    params = tuple(sorted(ROW_ENCODINGS))
    param_names = ("row_encoding",)
    timeout = 120

    def setup(self, row_encoding: str) -> None:
        rng = np.random.default_rng(0)
        self.k = np.arange(SAMPLES)
        self.t_ns = 1_700_000_000_000_000_000 + self.k * 1_000_000
        self.U, self.Z = rng.standard_normal((SAMPLES, 1)), rng.standard_normal((SAMPLES, 4))
        self.R = rng.standard_normal((3, SAMPLES, 5))
        self.frames = _traffic(FRAMES, "dc_motor_nominal")
        self.dir = tempfile.TemporaryDirectory()

    def teardown(self, row_encoding: str) -> None:
        self.dir.cleanup()

    def time_record(self, row_encoding: str) -> None:
        path = Path(self.dir.name) / "rows.mcap"
        with McapRecorder(path, row_encoding=row_encoding) as recorder:
            recorder.write_frames(self.frames, "ok")
            for lo in range(0, SAMPLES, 1024):
                hi = lo + 1024
                k, t = self.k[lo:hi], self.t_ns[lo:hi]
                recorder.write_samples(k, t, self.U[lo:hi], self.Z[lo:hi], np.zeros_like(k),
                                       ["V"], ["i_f", "i_a", "i_sum", "omega"])
                recorder.write_residual_rows(k, t, ["a:V", "s:i_f", "s:i_a", "s:i_sum",
                                                    "s:omega"], *(r[lo:hi] for r in self.R))
