"""Examples for the conformance suite: one config per registered method and a run of its plant
with a fault and lost data.

A method's example config is the first config in deploy/config whose ``method:`` names it (a new
method ships one and gets the suite for free); the test-only method ``tiny``
(tests/methods/tiny_method.py) is registered here, its example being the DC motor config with
``method: tiny``. The run is the emulated plant whose signals the config names (firmware_sim),
with its default noise, a sensor bias of 40 noise standard deviations at sample 800 and an
actuator bias (the papers' size for that plant) at 1800, never repaired, and lost samples (a
long gap, short gaps) and lost values (NaN commands and measurements) throughout.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import yaml

from canfdi import methods
from canfdi.config import parse_config
from canfdi.core.settings import MonitorConfig
from canfdi.firmware_sim.plants import PLANTS, make_plant
from canfdi.firmware_sim.scenario import parse_scenario
from canfdi.firmware_sim.simulate import simulate
from tests.conftest import REPO
from tests.methods import tiny_method

CONFIG_DIR = REPO / "deploy" / "config"
# Configs of methods that ship none (the test-only one): a shipped config with another method.
EXTRA_EXAMPLES = {"tiny": ("dc_motor.yaml", {"tiny": {"threshold": 8.0, "samples": 30}})}
# The papers' actuator faults: Chan et al. 2006's lambda 10 V, the output-error paper's 0.002,
# Hwang, Chang and Hsu's 1.0.
ACTUATOR_BIAS = {"dc_motor": 10.0, "winding_machine": 0.002, "vtol": 1.0}

methods.register(tiny_method.METHOD)


@dataclass(frozen=True)
class Example:
    """A method's config (its file and parsed form) and a run to diagnose: k, t_ns (N,),
    U (N, p), Z (N, q) with samples and values lost; the fault's sample and bias."""

    method: str
    path: Path
    document: dict
    config: MonitorConfig
    k: np.ndarray
    t_ns: np.ndarray
    U: np.ndarray
    Z: np.ndarray
    fault_sample: int
    fault_size: float


def example_document(method: str) -> tuple[Path, dict]:
    """(config file, YAML document) of the method's example config."""
    if method in EXTRA_EXAMPLES:
        name, changes = EXTRA_EXAMPLES[method]
        path = CONFIG_DIR / name
        doc = yaml.safe_load(path.read_text())
        doc.update(changes, method=method)
        return path, doc
    for path in sorted(CONFIG_DIR.glob("*.yaml")):
        doc = yaml.safe_load(path.read_text())
        if doc.get("method", "parity") == method:
            return path, doc
    raise AssertionError(f"method {method!r} has no example config in {CONFIG_DIR}: ship one "
                         "(or add it to EXTRA_EXAMPLES if it is test-only)")


def _plant_of(config: MonitorConfig) -> str:
    for name in PLANTS:
        plant = make_plant(name)
        if (plant.input_names, plant.output_names) == (tuple(config.inputs),
                                                       tuple(config.outputs)):
            return name
    raise AssertionError(f"no emulated plant has the signals of {config.name}")


_CACHE: dict[str, Example] = {}


def make_example(method: str) -> Example:
    if method in _CACHE:
        return _CACHE[method]
    path, doc = example_document(method)
    config = parse_config(doc, path)
    plant = _plant_of(config)
    noise = make_plant(plant).noise_defaults().measurement
    duration_samples = 3000
    dt = config.model.dt or 0.01
    onset = 800
    bias = 40.0 * float(noise[0])
    scenario = parse_scenario({
        "plant": plant, "duration": duration_samples * dt, "seed": 7,
        "faults": [{"target": "sensor", "index": 0, "onset": onset * dt, "bias": bias},
                   {"target": "actuator", "index": 0, "onset": 1800 * dt, "eta": 1.0,
                    "lambda": ACTUATOR_BIAS[plant]}],
    })
    run = simulate(scenario)
    rng = np.random.default_rng(11)
    keep = np.ones(len(run.k), dtype=bool)
    keep[300:340] = False  # a long gap: windows restart
    for start in (500, 1000, 1600):
        keep[start: start + rng.integers(1, 3)] = False  # short gaps
    U, Z = run.u_c.copy(), run.z.copy()
    lost = rng.random(Z.shape) < 0.004
    Z[lost] = np.nan
    U[rng.random(U.shape) < 0.004] = np.nan
    k = run.k[keep]
    example = Example(method=method, path=path, document=doc, config=config, k=k,
                      t_ns=(k * round(dt * 1e9)).astype(np.int64), U=U[keep], Z=Z[keep],
                      fault_sample=onset, fault_size=bias)
    _CACHE[method] = example
    return example


@pytest.fixture(params=sorted(methods.names()))
def example(request) -> Example:
    """One example per registered method (the suite runs on every one)."""
    return make_example(request.param)
