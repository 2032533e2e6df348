"""`canfdi design CONFIG`: which faults are detectable, isolable, estimable; which window."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import replace

import numpy as np

from canfdi.config import ConfigError, load_config
from canfdi.core.design import Design, design_bank, design_to_dict

HELP = """\
Design the fully decoupled parity residuals of a monitor config and analyse them.

For each actuator: the parity vector that sees that actuator only (Chan et al. 2006 eq. 13,
Theorems 1 and 3); for each sensor: the vector blind to that sensor (eq. 20, Theorem 2);
windows are the smallest admissible unless the config fixes them. For each fault: detectable
and strongly detectable with the unknown inputs decoupled (Nyberg and Nielsen, Theorems 2, 3),
which residuals respond (isolability; faults with the same signature cannot be told apart),
whether a sensor bias can be estimated jointly with all the others from the sensor bank (eq.
41), and the fault-to-noise gap (response to a unit constant fault over the residual's noise
standard deviation) at several window orders so they can be compared.

Exit status: 0 on success, 2 on a bad config (the message names the field)."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("design", help="design and analyse the parity residuals of a config",
                       description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("config", help="monitor config (YAML), e.g. deploy/config/dc_motor.yaml")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    p.add_argument("--actuator-window", type=int, metavar="S",
                   help="override the config's actuator window order")
    p.add_argument("--sensor-window", type=int, metavar="S",
                   help="override the config's sensor window order")


def run(args: argparse.Namespace) -> int:
    try:
        config = load_config(args.config)
        options = config.design
        for attr in ("actuator_window", "sensor_window"):
            value = getattr(args, attr)
            if value is not None:
                if value < 0:
                    raise ConfigError(f"--{attr.replace('_', '-')}", "must be >= 0")
                options = replace(options, **{attr: value})
    except ConfigError as exc:
        print(f"canfdi design: config error: {exc}", file=sys.stderr)
        return 2
    design = design_bank(config.model, config.inputs, config.outputs, options)
    if args.json:
        print(json.dumps({"config": config.name, **design_to_dict(design)}, indent=2))
    else:
        print(render_text(config.name, design))
    return 0


def _fmt(x: float | None, spec: str = ".4g") -> str:
    return "-" if x is None or not np.isfinite(x) else format(x, spec)


def render_text(name: str, design: Design) -> str:
    d = design_to_dict(design)
    m = d["model"]
    lines = [
        f"canfdi design: {name}",
        f"model: n={m['n']} states, p={m['p']} actuators, q={m['q']} sensors, "
        f"r={m['r']} state unknown inputs, r1={m['r1']} output unknown inputs, "
        f"{m['time']}, dt={m['dt']}",
        f"windows: actuator s={d['windows']['actuator']}, sensor s={d['windows']['sensor']}",
        "",
        "Residuals (fault-to-noise = response to a unit constant fault / noise std)",
        f"  {'residual':<24}{'s':>3}{'min s':>7}{'sensitivity':>13}{'noise std':>11}"
        f"{'fault/noise':>13}  notes",
    ]
    for kind in ("actuators", "sensors"):
        for e in d[kind]:
            label = f"{kind[:-1]} {e['index']} {e['name']}"
            if e["exists"]:
                note = ("sees " + ", ".join(e["sees"])) if kind == "sensors" else "sees itself only"
                lines.append(
                    f"  {label:<24}{e['window']:>3}{_fmt(e['min_window'], 'd'):>7}"
                    f"{_fmt(e['sensitivity']):>13}{_fmt(e['noise_std']):>11}"
                    f"{_fmt(e['fault_to_noise']):>13}  {note}")
            else:
                lines.append(f"  {label:<24}{e['window']:>3}{_fmt(e['min_window'], 'd'):>7}"
                             f"  NO VECTOR: {e['reason']}")
    lines += ["", "Faults (unknown inputs decoupled; Nyberg and Nielsen Theorems 2 and 3)"]
    lines.append(f"  {'fault':<24}{'detect':>8}{'strong':>8}{'isolable':>10}{'joint est':>11}"
                 f"{'best f/n':>10}  residuals / notes")
    for e in d["detectability"]:
        label = f"{e['kind']} {e['index']} {e['name']}"
        est = "-" if "jointly_estimable" not in e else ("yes" if e["jointly_estimable"] else "no")
        notes = ", ".join(e["residuals"]) or "none"
        if e["confused_with"]:
            notes += f"; same signature as {', '.join(e['confused_with'])}"
        lines.append(
            f"  {label:<24}{'yes' if e['detectable'] else 'NO':>8}"
            f"{'yes' if e['strongly_detectable'] else 'no':>8}"
            f"{'yes' if e['isolable'] else 'no':>10}{est:>11}"
            f"{_fmt(e['best_fault_to_noise']):>10}  {notes}")
        if e["reason"]:
            lines.append(f"      {e['reason']}")
        if e.get("jointly_estimable") is False and e["strongly_detectable"]:
            lines.append("      with all sensor biases estimated together (eq. 41) this one is "
                         "tied to others; alone (single fault) it can be estimated")
    if "detectability_discrete" in d:
        lines += ["", "Discretised model (the one the monitor runs)"]
        for e in d["detectability_discrete"]:
            lines.append(f"  {e['kind']} {e['index']}: detectable "
                         f"{'yes' if e['detectable'] else 'no'}, strongly "
                         f"{'yes' if e['strongly_detectable'] else 'no'}")
    lines += ["", "Isolability (gain of each residual to a unit constant fault; "
              ". = no response at all)"]
    iso = d["isolability"]
    width = max(10, *(len(f) + 2 for f in iso["faults"]))
    lines.append("  " + " " * 20 + "".join(f"{f:>{width}}" for f in iso["faults"]))
    for rname, row, resp in zip(iso["residuals"], iso["gain"], iso["responds"], strict=True):
        cells = "".join(f"{(format(g, '.3g') if r else '.'):>{width}}"
                        for g, r in zip(row, resp, strict=True))
        lines.append(f"  {rname:<20}{cells}")
    lines += ["", "Window comparison (fault-to-noise by window order s)"]
    for c in d["window_comparison"]:
        cells = "  ".join(f"s={w['window']}: {_fmt(w.get('fault_to_noise'))}"
                          if w["exists"] else f"s={w['window']}: none" for w in c["by_window"])
        lines.append(f"  {c['kind']} {c['index']} {c['name']:<14} {cells}")
    return "\n".join(lines)
