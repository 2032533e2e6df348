"""The docs site's figures, made from real runs at build time (issue 44): the emulator plays a
drive, the monitor diagnoses it, and the verbs draw what they draw for a user.

    python docs/_ext/figures.py OUT_DIR

runs, each as its own `canfdi` process, as a user would:

- `canfdi demo -o` and `canfdi report`: a diagnosed run (residuals against their thresholds,
  the diagnoses marked), an accepted fault's estimates converging, and a run of each method;
- `canfdi design --json`: the design's isolability, drawn with the look `canfdi report` uses
  (canfdi.tools.figures);
- `canfdi evaluate`: the detection delay against the fault-to-noise ratio;
- `canfdi sim` and `canfdi fleet`: ten days of one drive whose i_f sensor bias creeps up, and
  the fleet report's trend of it (the report itself goes into the site too).

Writes OUT_DIR/figures/*.png, OUT_DIR/runs/ (the runs' files: the reference pages read
runs/demo.mcap's channels) and OUT_DIR/site-extra/fleet-report/; prints what it wrote. Takes
about a minute on one core.
"""

from __future__ import annotations

import base64
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
FLEET_DAYS = 10
FLEET_START = 1_793_491_200  # 2026-11-01 00:00 UTC: each day's log is moved to its day
EVALUATE_RUNS = 40


def canfdi(*args: str, cwd: Path) -> str:
    """Run a verb as its own process; its stdout (a failure is the build's failure)."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run([sys.executable, "-m", "canfdi", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=900)
    if done.returncode != 0:
        raise RuntimeError(f"canfdi {' '.join(args)} ended {done.returncode}: "
                           f"{done.stderr.strip()[-2000:]}")
    return done.stdout


DEMO_RUNS = (
    # (log stem, the demo's options, (report figure, site figure)...): the demo's run (its
    # log is the one the reference's topics page reads), then the output_error and uio
    # methods' pages (the parity method's shows the demo's estimates-converging.png)
    ("demo", (), (("residuals.png", "diagnosed-run.png"),
                  ("fault_1_actuator_V.png", "estimates-converging.png"))),
    ("method-output-error", ("--scenario", "winding_machine_consecutive", "--config",
                             str(REPO / "deploy/config/winding_machine_oe.yaml")),
     (("overview.png", "method-output-error.png"),)),
    ("method-uio", ("--scenario", "vtol_actuators", "--config",
                    str(REPO / "deploy/config/vtol_uio.yaml")),
     (("residuals.png", "method-uio.png"),)),
)


def demo_runs(out: Path, figures: Path) -> list[Path]:
    """Each run of DEMO_RUNS: `canfdi demo ... -o STEM.mcap`, `canfdi report STEM.mcap`, and
    the report's figures copied under their site names."""
    written = []
    for stem, options, picks in DEMO_RUNS:
        canfdi("demo", *options, "-o", f"{stem}.mcap", "--no-live", "--json", cwd=out)
        report = json.loads(canfdi("report", f"{stem}.mcap", "-o", stem, "--json",
                                   "--no-progress", cwd=out))
        for source, name in picks:
            path = next(Path(out, p) for p in report["figures"] if p.endswith(source))
            written.append(Path(shutil.copyfile(path, figures / name)))
    return written


def isolability(out: Path, figures: Path) -> Path:
    import numpy as np

    from canfdi.tools.figures import new_figure

    design = json.loads(canfdi("design", str(REPO / "deploy/config/dc_motor.yaml"), "--json",
                               cwd=out))
    iso = design["isolability"]
    response = np.abs(np.asarray(iso["response"], dtype=float))
    seen = response > 1e-9 * response.max()
    fig, axes = new_figure(1, 1, height=2.6, width=7.0, sharex=False)
    ax = axes[0, 0]
    ax.grid(False)
    ax.imshow(seen, cmap="Blues", vmin=0, vmax=1.4, aspect="auto")
    for (i, j), on in np.ndenumerate(seen):
        ax.text(j, i, f"{response[i, j]:.2g}" if on else "0", ha="center", va="center",
                fontsize=8, color="black")
    ax.set_xticks(range(len(iso["faults"])), iso["faults"])
    ax.set_yticks(range(len(iso["residuals"])), iso["residuals"])
    ax.set_xlabel("fault on this channel (identical columns: faults that cannot be told apart)")
    ax.set_ylabel("residual")
    ax.set_title("canfdi design: each residual's response to each fault (dc_motor.yaml)",
                 fontsize=10)
    path = figures / "isolability.png"
    fig.savefig(path, dpi=110)
    return path


def evaluation(out: Path, figures: Path) -> Path:
    canfdi("evaluate", "--plant", "dc_motor", "--runs", str(EVALUATE_RUNS), "-o", "evaluate",
           "--no-progress", cwd=out)
    return Path(shutil.copyfile(out / "evaluate" / "dc_motor_parity.png",
                                figures / "delay-vs-fnr.png"))


def _moved(log: Path, seconds: float) -> None:
    """A candump log's timestamps moved by ``seconds`` (the emulator starts every log at 0)."""
    text = re.sub(r"^\((\d+\.\d+)\)",
                  lambda m: f"({float(m.group(1)) + seconds:.6f})", log.read_text(), flags=re.M)
    log.write_text(text)


def fleet(out: Path, site_out: Path, figures: Path) -> list[Path]:
    drives = out / "fleet" / "logs"
    for drive, creep in (("press-1", 0.03), ("press-2", 0.0)):
        (drives / drive).mkdir(parents=True, exist_ok=True)
        for day in range(FLEET_DAYS):
            scenario = out / "fleet" / f"{drive}-day{day:02d}.yaml"
            scenario.write_text(
                f"name: {drive}-day{day:02d}\nplant: dc_motor\nduration: 20.0\n"
                f"seed: {100 + day}\nnoise: {{measurement: 0.01, process: 0.0}}\nfaults:\n"
                f"  - {{target: sensor, index: 0, onset: 10.0, bias: {0.2 + creep * day:.3f}}}\n")
            log = drives / drive / f"day{day:02d}.log"
            canfdi("sim", "--scenario", str(scenario), "--speed", "0", "-o", str(log),
                   "--quiet", cwd=out)
            _moved(log, FLEET_START + day * 86400 + 8 * 3600)
    canfdi("fleet", str(drives), "--config", str(REPO / "deploy/config/dc_motor.yaml"),
           "-o", str(out / "fleet" / "fleet.parquet"), "--jobs", "1", "--no-progress",
           cwd=out)
    report = out / "fleet" / "fleet-report"
    site = site_out / "site-extra" / "fleet-report"
    shutil.rmtree(site, ignore_errors=True)
    shutil.copytree(report, site)
    page = (report / "press-1.html").read_text()
    images = re.findall(r'src="data:image/png;base64,([^"]+)"', page)
    # the drive page's figures: its fault timeline, then its estimates over time with the trend
    trend = figures / "fleet-trend.png"
    trend.write_bytes(base64.b64decode(images[1]))
    return [trend, site / "index.html"]


def make(out: Path) -> list[Path]:
    """Every run afresh in OUT/runs; the figures in OUT/figures, the fleet report in
    OUT/site-extra/fleet-report."""
    runs, figures = out / "runs", out / "figures"
    for directory in (runs, figures):
        shutil.rmtree(directory, ignore_errors=True)
        directory.mkdir(parents=True)
    written = demo_runs(runs, figures)
    written.append(isolability(runs, figures))
    written.append(evaluation(runs, figures))
    written += fleet(runs, out, figures)
    return written


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    for path in make(Path(sys.argv[1]).resolve()):
        print(f"wrote {path}")
