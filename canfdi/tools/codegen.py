"""`canfdi codegen`: a drive's monitor as a self-contained C project for its MCU.

The project is the C core's own files (canfdi/_c, the ones the daemon's extension compiles)
and the drive's tables as const data generated from its config: the signal table and E2E
profiles (canfdi.bus.ctables), the counter clock's and time gate's parameters, the residual
bank's FIR blocks, noise and Page-Hinkley thresholds, the diagnosis' hypotheses and settings
(canfdi.methods.parity). Tables, never logic: every number comes from the objects the Python
monitor runs with, so the two compute the same thing.

The drive loop in C (canfdi/_c/drive.c, diagnose.c, compensate.c) detects and diagnoses
every fault as the parity diagnoser does (named, accepted, refined, or the alarm unexplained;
compensated and reset for the next; the accepted faults tracked), announced by FDI_FAULT and
FDI_ESTIMATE, with FDI_STATUS when the caller's timer asks.
"""

from __future__ import annotations

import math
import shutil
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from canfdi.bus.frames import STATUS_NAMES, VALID_STATUSES
from canfdi.core.settings import ConfigError, MonitorConfig

__all__ = ["CORE_FILES", "CodegenRefused", "DriveTables", "MonitorMessage", "drive_tables",
           "memory_sizes", "render", "write_project"]

CORE_FILES = ("cfdi.h", "decode.h", "e2e.h", "encode.h", "drive.h", "drive_impl.h",
              "lagged.h", "track.h", "bank.c", "counter.c", "decide.c", "decode.c", "detect.c",
              "e2e.c", "encode.c", "gate.c", "info.c", "lagged.c", "track.c", "track_check.c",
              "compensate.c", "diagnose.c", "decisions.c", "drive.c", "drive_init.c",
              "announce.c", "cfdi_run.c",
              "cfdi_io.h",
              "cfdi_io_host.c", "cfdi_io_semihost.c", "m4f_startup.c", "m4f.ld", "stack.awk")
"""The C core's files a project holds (canfdi/_c; not _kernel.c, the CPython face), with the
runner and its two I/O sides (host stdio, MCU semihosting) and the Cortex-M4F's startup and
memory map."""


class CodegenRefused(ConfigError):
    """The config asks for something the C drive loop does not do (field, what instead)."""


@dataclass(frozen=True)
class MonitorMessage:
    """One monitor message as the C loop sends it: its tables (canfdi.bus.ctables.message_tables)
    and each encode.h role's modulus and cap (canfdi.monitor.WRAPS, CAPS; 0: none)."""

    tables: object
    wrap: tuple[float, ...]
    cap: tuple[float, ...]


@dataclass(frozen=True)
class DriveTables:
    """Everything the generated tables hold, as arrays: the bus's (canfdi.bus.ctables), the
    clock's and gate's (SampleAssembler.c_params), the bank's and detectors', the monitor's
    messages and codes (canfdi.monitor), the diagnosis' (ParityDiagnoser.c_tables)."""

    name: str
    bus: object  # canfdi.bus.ctables.BusTables
    clock: dict
    p: int
    q: int
    coef: np.ndarray  # (S+1, q+p, m)
    uses: np.ndarray  # (S+1, q+p, m) uint8
    sigma: np.ndarray  # (m,)
    delta: np.ndarray  # (m,)
    h: np.ndarray  # (m,)
    residual_names: tuple[str, ...]
    messages: dict = field(default_factory=dict)  # FDI_FAULT, FDI_ESTIMATE, FDI_STATUS -> ...
    codes: dict = field(default_factory=dict)  # the monitor's codes (`_monitor_codes`)
    drive_index: int = 0
    diag: dict | None = None  # the diagnosis' (ParityDiagnoser.c_tables); None: none in C
    input_names: tuple[str, ...] = ()
    output_names: tuple[str, ...] = ()
    status_period: float = 1.0

    @property
    def tx_frames(self) -> int:
        """The frames the C loop's queue holds: the most one sample can announce (a decision's
        or a tracker's checkpoint's, after a detection) and a heartbeat."""
        worst = 1
        if self.diag is not None:
            members = int(self.diag["d"])
            tracked = int(self.diag["track"]["max_params"])
            worst = 1 + max(5 * members, 1 + 3 * members, 2 * tracked + 2)
        return worst + 1


def _refuse_unsupported(config: MonitorConfig, doc: dict) -> None:
    """One line naming the field for each thing the C loop does not do (the first found; the
    method's own limits are its `c_tables`')."""
    from canfdi import methods

    if methods.get(config.method).c_tables is None:
        raise CodegenRefused("method", f"the C drive loop has no tables for the method "
                                       f"{config.method!r}")
    if len(config.drive_list) != 1:
        raise CodegenRefused("drives", "one drive per MCU: generate a project per drive "
                                       f"(this config has {len(config.drive_list)})")
    if config.bus.clock.kind != "counter":
        raise CodegenRefused("bus.clock.kind", "the C drive loop has the counter clock; "
                                               f"this config asks for {config.bus.clock.kind!r}")
    watchdog = doc.get("watchdog")
    if isinstance(watchdog, dict) and watchdog.get("enabled", True):
        raise CodegenRefused("watchdog.enabled", "the noise watchdog stays on the gateway: "
                                                 "set it false (or leave the section out)")
    if doc.get("teach_in"):
        raise CodegenRefused("teach_in", "teach-in stays on the gateway")


def drive_tables(config: MonitorConfig, doc: dict | None = None) -> DriveTables:
    """The tables of a config's drive, read off the objects the Python monitor runs with.

    Raises
    ------
    ConfigError
        The config asks for what the C loop does not do (naming the field).
    """
    from canfdi.bus.assembler import SampleAssembler
    from canfdi.core import kernel
    from canfdi.monitor import Monitor

    _refuse_unsupported(config, doc or {})
    monitor = Monitor(config, diagnose=False, kernel=kernel.get("python"))
    drive = monitor.drives[0]
    if not isinstance(drive.clock, SampleAssembler):  # pragma: no cover - refused above
        raise CodegenRefused("bus.clock.kind", "the C drive loop has the counter clock")
    tables = drive.bus_map.c_tables()
    if not tables.fits:
        raise CodegenRefused("bus.dbc", "a message has more signals than the C core takes")
    detection = monitor.method.c_tables(config)
    diag = detection.get("diag")
    if diag is not None:
        st = diag["settings"]
        kept = int(st.lookback) + int(st.onset_before) + DETECTION_DELAY
        detection["diag"] = diag = {**diag, "lookback": min(kept, diag["recent"])}
    if diag is not None and diag["d"] > MAX_FAULTS:
        raise CodegenRefused("signals.outputs", f"a joint fit of {diag['d']} sensors: the C "
                                                f"diagnosis takes {MAX_FAULTS} at most")
    return DriveTables(name=drive.name, bus=tables, clock=drive.clock.c_params(),
                       p=len(config.inputs), q=len(config.outputs),
                       messages=_messages(monitor), codes=_monitor_codes(monitor, drive),
                       drive_index=drive.index, input_names=tuple(config.inputs),
                       output_names=tuple(config.outputs),
                       status_period=float(config.bus.status_period), **detection)


def _messages(monitor) -> dict[str, MonitorMessage]:
    """FDI_FAULT, FDI_ESTIMATE and FDI_STATUS as the C loop encodes them (their tables, each
    signal's role from canfdi.monitor.MONITOR_ROLES, the counts' moduli and caps); {} for a
    listen-only monitor, which sends nothing."""
    from canfdi.bus.ctables import ENCODE_H, message_tables
    from canfdi.monitor import CAPS, MONITOR_ROLES, WRAPS

    frames = monitor.frames
    if not frames.transmit:
        return {}
    out = {}
    for name, roles in MONITOR_ROLES.items():
        try:
            tables = message_tables(frames.layouts[name], frames.keys[name],
                                    frames.profile(name), roles)
        except ValueError as exc:
            raise CodegenRefused("bus.monitor.dbc", str(exc)) from None
        wrap, cap = [0.0] * ENCODE_H["CFDI_N_ROLES"], [0.0] * ENCODE_H["CFDI_N_ROLES"]
        for signal, modulus in WRAPS.get(name, {}).items():
            wrap[ENCODE_H[f"CFDI_ROLE_{roles[signal]}"]] = float(modulus)
        for signal, most in CAPS.get(name, {}).items():
            cap[ENCODE_H[f"CFDI_ROLE_{roles[signal]}"]] = float(most)
        out[name] = MonitorMessage(tables, tuple(wrap), tuple(cap))
    return out


def _monitor_codes(monitor, drive) -> dict[str, tuple[float, ...]]:
    """The codes the C loop writes, read off the monitor's own values (one place): FDI_FAULT's
    State of a detection, a naming and an acceptance; the Kind of none, an actuator and a sensor;
    FDI_ESTIMATE's Param of eta, lambda and bias and what a standard deviation adds; FDI_STATUS's
    State of monitoring, diagnosing and named."""
    from canfdi.core.records import FaultEvent

    def fault(kind: str, target: str | None) -> dict:
        return monitor.fault_values(FaultEvent(kind=kind, sample=0, timestamp_ns=0,
                                               target=target), drive)

    event = FaultEvent(kind="accepted", sample=0, timestamp_ns=0, target="sensor", index=0)
    params = tuple(float(monitor.estimate_values(event, key, 0.0, drive)["Param"])
                   for key in ("eta", "lambda", "bias"))
    std = float(monitor.estimate_values(event, "eta", 0.0, drive, True)["Param"]) - params[0]
    return {"fault_states": tuple(float(fault(k, None)["State"])
                                  for k in ("detected", "named", "accepted")),
            "kinds": tuple(float(fault("detected", t)["Kind"])
                           for t in (None, "actuator", "sensor")),
            "params": params, "std_param": (std,),
            "status_states": tuple(float(monitor.status_values(drive, state)["State"])
                                   for state in ("monitoring", "diagnosing", "named"))}


MAX_FAULTS = 4
"""drive.h's CFDI_MAX_FAULTS: the members of a joint fit the C diagnosis accepts at once."""

DETECTION_DELAY = 8
"""Samples after its change point a fault is detected within, for which a drive's diagnosis
keeps the samples its onsets and look-back need (identification.lookback and onset_before
before the change point, and these): a fault detected later is fitted from the oldest kept,
so its onsets, and with compensated channels its fits' costs, may differ from the gateway's,
which keeps identification.max_samples of them."""


def _real(v: float) -> str:
    if math.isnan(v):
        return "NAN"
    if math.isinf(v):
        return "INFINITY" if v > 0 else "-INFINITY"
    return repr(float(v))


def _int64(v: int) -> str:
    v = int(v)
    if v == -(2 ** 63):
        return "(-INT64_C(9223372036854775807) - 1)"
    return f"INT64_C({v})"


def _array(ctype: str, name: str, values: np.ndarray, fmt, per_line: int = 8) -> str:
    items = [fmt(v) for v in np.asarray(values).ravel()]
    if not items:  # C99 has no empty arrays: one unused element, the size says 0
        items = [fmt(0)]
    lines = [", ".join(items[i:i + per_line]) for i in range(0, len(items), per_line)]
    body = ",\n    ".join(lines)
    return f"static const {ctype} {name}[{len(items)}] = {{\n    {body}\n}};\n"


def _string(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def memory_sizes(t: DriveTables, float32: bool) -> dict[str, int]:
    """The sizes drive.h's CFDI_DRIVE_MEMORY lays a drive's memory out by (cfdi_drive_init
    carves the same), and the bytes of each part, as drive.c's carve takes them."""
    S1, _, m = t.coef.shape
    S, W, P = S1 - 1, t.p + t.q, t.p
    g = t.diag
    z = {"W": W, "VW": int(t.bus.width), "S": S, "M": m, "P": P, "X": t.tx_frames,
         "L": max((msg.tables.length for msg in t.messages.values()), default=0)}
    if g is not None:
        st = g["settings"]
        z.update(H=len(g["table"].kind), D=int(g["d"]),
                 K=int(st.max_onsets) + int(g["max_earlier"]),
                 R=int(g["lookback"]) + S + max(2 * S, int(st.min_samples)) + 1,
                 Y=S + int(st.onset_before) + 1, NC=len(g["lagged"]["cols"]),
                 NP=len(g["lagged"]["pairs"]), T=int(g["track"]["max_params"]))
    return z


def render(t: DriveTables, config_name: str) -> dict[str, str]:
    """{file name: text} of the generated tables: cfdi_tables.h (sizes, declarations) and
    cfdi_tables.c (the const data)."""
    b = t.bus
    S1, _, m = t.coef.shape
    g = t.diag
    z = memory_sizes(t, False)
    defines = "".join(f"#define CFDI_GEN_{key} {value}\n" for key, value in z.items())
    if g is not None:
        memory = ("CFDI_DRIVE_MEMORY(CFDI_GEN_W, CFDI_GEN_VW, CFDI_GEN_S, CFDI_GEN_M, CFDI_GEN_P, "
                  "CFDI_GEN_H, CFDI_GEN_D, CFDI_GEN_K, CFDI_GEN_R, CFDI_GEN_Y, CFDI_GEN_NC, "
                  "CFDI_GEN_NP, CFDI_GEN_T, CFDI_GEN_X, CFDI_GEN_L)")
    else:
        memory = ("CFDI_DRIVE_MEMORY_MONITOR(CFDI_GEN_W, CFDI_GEN_VW, CFDI_GEN_S, CFDI_GEN_M, "
                  "CFDI_GEN_X, CFDI_GEN_L)")
    header = f"""/* Generated by `canfdi codegen` from {config_name}: the tables of drive {t.name}.
 * Data, not logic; do not edit (generate again). */
#ifndef CFDI_TABLES_H
#define CFDI_TABLES_H

#include "drive.h"

/* The drive's sizes (drive.h's CFDI_DRIVE_MEMORY names them): a sample's width W (P inputs,
 * then outputs), the bus's value width VW, the bank's window S and residuals M; the diagnosis'
 * hypotheses H, parameters D, onsets K, rows kept R and history Y, the lagged middles'
 * columns NC and pairs NP, the tracker's parameters T; frames queued X of L bytes at most. */
{defines}#define CFDI_GEN_MEMORY ({memory})  /* bytes */
#define CFDI_GEN_STATUS_PERIOD_NS INT64_C({round(t.status_period * 1e9)})  /* the heartbeat */

extern const cfdi_drive_tables cfdi_drive_tables_gen;
extern const char *const cfdi_drive_name;
extern const char *const cfdi_status_names[CFDI_N_STATUS];
extern const char *const cfdi_residual_names[CFDI_GEN_M];
extern const char *const cfdi_input_names[CFDI_GEN_P];
extern const char *const cfdi_output_names[{t.q}];

#endif
"""
    c = t.clock
    dest = np.asarray(c["dest"], dtype=np.int64)
    parts = [f"/* Generated by `canfdi codegen` from {config_name}: drive {t.name}. */\n"
             "#include <math.h>\n#include <stdint.h>\n\n#include \"cfdi_tables.h\"\n\n"]
    parts.append(_array("int64_t", "std_id", b.std_id, _int64))
    parts.append(_array("int32_t", "std_entry", b.std_entry, str, 16))
    parts.append(_array("int64_t", "ext_id", b.ext_id, _int64))
    parts.append(_array("int32_t", "ext_entry", b.ext_entry, str))
    parts.append(_array("int64_t", "entry", b.entry, _int64))
    parts.append(_array("int32_t", "e2e_spec", b.e2e_spec, str, 16))
    parts.append(_array("uint8_t", "e2e_bytes", b.e2e_bytes, str, 16))
    parts.append(_array("int64_t", "sig_int", b.sig_int, _int64))
    parts.append(_array("double", "sig_real", b.sig_real, _real, 4))
    parts.append(_array("int64_t", "ids_int", b.ids_int, _int64))
    parts.append(_array("double", "ids_real", b.ids_real, _real, 4))
    parts.append(_array("int64_t", "dest", dest, _int64))
    parts.append(_array("cfdi_real", "coef", t.coef, _real, 4))
    parts.append(_array("uint8_t", "uses", t.uses, str, 16))
    parts.append(_array("cfdi_real", "sigma", t.sigma, _real, 4))
    parts.append(_array("cfdi_real", "delta", t.delta, _real, 4))
    parts.append(_array("cfdi_real", "h", t.h, _real, 4))
    parts.append(_array("uint8_t", "valid_status",
                        [1 if s in VALID_STATUSES else 0 for s in STATUS_NAMES], str, 16))
    messages = {}
    for name, tag in (("FDI_FAULT", "fault"), ("FDI_ESTIMATE", "estimate"),
                      ("FDI_STATUS", "status")):
        msg = t.messages.get(name)
        if msg is None:
            messages[tag] = "{ NULL, { 0 }, { 0 } }"
            continue
        f = msg.tables
        parts.append(_array("int32_t", f"{tag}_e2e_spec", f.e2e_spec, str, 16))
        parts.append(_array("uint8_t", f"{tag}_e2e_bytes", f.e2e_bytes, str, 16))
        parts.append(_array("int64_t", f"{tag}_sig_int", f.sig_int, _int64))
        parts.append(_array("double", f"{tag}_sig_real", f.sig_real, _real, 3))
        parts.append(f"""
/* {name} (the monitor DBC's layout, its E2E). */
static const cfdi_message {tag}_msg = {{
    {f.frame_id}u, {int(f.extended)}, {f.length},
    {tag}_e2e_spec, {tag}_e2e_bytes,
    {tag}_sig_int, {tag}_sig_real, {len(f.sig_int)}
}};
""")
        messages[tag] = (f"{{ &{tag}_msg, {{ {', '.join(_real(v) for v in msg.wrap)} }}, "
                         f"{{ {', '.join(_real(v) for v in msg.cap)} }} }}")
    if g is not None:
        parts.append(_diag_tables(g, t))
    codes = t.codes or {"fault_states": (0.0,) * 3, "kinds": (0.0,) * 3, "params": (0.0,) * 3,
                        "std_param": (0.0,), "status_states": (0.0,) * 3}

    def reals(key: str) -> str:
        return ", ".join(_real(v) for v in codes[key])

    parts.append(f"""
static const cfdi_bus bus = {{
    std_id, std_entry, {len(b.std_id)}, ext_id, ext_entry, {len(b.ext_id)},
    entry, {len(b.entry)}, {b.n_slots},
    e2e_spec, e2e_bytes, {len(b.e2e_spec)},
    sig_int, sig_real, {len(b.sig_int)},
    ids_int, ids_real, {len(b.ids_int)},
    {b.width}
}};

const cfdi_drive_tables cfdi_drive_tables_gen = {{
    .bus = &bus,
    .gate_bound = {_int64(c["gate_bound"])}, .gate_confirm = {_int64(c["gate_confirm"])},
    .dest = dest, .n_slots = {dest.shape[0]}, .cols = {dest.shape[1]},
    .mod = {_int64(c["mod"])}, .dt_ns = {_real(c["dt_ns"])}, .slack = {_real(c["slack"])},
    .p = {t.p}, .q = {t.q},
    .coef = coef, .uses = uses, .S = {S1 - 1}, .m = {m},
    .sigma = sigma, .delta = delta, .h = h,
    .fault = {messages["fault"]},
    .estimate = {messages["estimate"]},
    .status = {messages["status"]},
    .drive_index = {float(t.drive_index)!r},
    .fault_states = {{ {reals("fault_states")} }},
    .kinds = {{ {reals("kinds")} }},
    .params = {{ {reals("params")} }},
    .std_param = {reals("std_param")},
    .status_states = {{ {reals("status_states")} }},
    .tx_frames = {t.tx_frames},
    .valid_status = valid_status,
    .diag = {"&diag" if g is not None else "NULL"}
}};

const char *const cfdi_drive_name = {_string(t.name)};
const char *const cfdi_status_names[CFDI_N_STATUS] = {{
    {", ".join(_string(s) for s in STATUS_NAMES)}
}};
const char *const cfdi_residual_names[CFDI_GEN_M] = {{
    {", ".join(_string(s) for s in t.residual_names)}
}};
const char *const cfdi_input_names[CFDI_GEN_P] = {{
    {", ".join(_string(s) for s in t.input_names)}
}};
const char *const cfdi_output_names[{t.q}] = {{
    {", ".join(_string(s) for s in t.output_names)}
}};
""")
    return {"cfdi_tables.h": header, "cfdi_tables.c": "".join(parts)}


def _diag_tables(g: dict, t: DriveTables) -> str:
    """The diagnosis' const data (drive.h's cfdi_diag_tables)."""
    table, st = g["table"], g["settings"]
    lg, tk = g["lagged"], g["track"]
    H = len(table.kind)
    S1, _, m = t.coef.shape
    parts = [_array("int8_t", "hyp_kind", table.kind, str, 16),
             _array("int32_t", "hyp_index", table.index, str, 16),
             _array("int32_t", "hyp_n_params", table.n_params, str, 16),
             _array("int32_t", "hyp_full", table.full, str, 16),
             _array("int64_t", "hyp_name_key", table.name_key, _int64, 4),
             _array("uint8_t", "hyp_twins", table.twins, str, 16),
             _array("cfdi_real", "hyp_penalty", table.penalty, _real, 4),
             _array("int32_t", "diag_columns", g["columns"], str, 16),
             _array("cfdi_real", "diag_Gz", g["Gz"], _real, 4),
             _array("cfdi_real", "diag_Gu", g["Gu"], _real, 4),
             _array("cfdi_real", "diag_gamma", g["gamma"], _real, 4),
             _array("cfdi_real", "diag_units", g["units"], _real, 4),
             _array("int32_t", "lag_cols", lg["cols"], str, 16),
             _array("int32_t", "lag_hyp_cols", lg["hyp_cols"], str, 16),
             _array("int32_t", "lag_pairs", lg["pairs"], str, 16),
             _array("int32_t", "lag_hyp_pairs", lg["hyp_pairs"], str, 16),
             _array("cfdi_real", "lag_noise", g["noise"], _real, 4),
             _array("cfdi_real", "lag_steady", lg["steady"], _real, 4),
             _array("double", "track_chi2", tk["chi2"], _real, 4),
             _array("cfdi_real", "track_ratio", tk["ratio"], _real, 4),
             _array("cfdi_real", "track_unit", tk["unit"], _real, 4),
             _array("int32_t", "twin_order", g["twin_order"], str, 16),
             _array("cfdi_real", "twin_ratio", g["twin_ratio"], _real, 4)]
    own = ", ".join(_real(v) for v in g["own_chi2"])
    parts.append(f"""
/* The diagnosis: its hypotheses, settings and what their fits are made of; the events'
 * variances lag by lag (lagged.h); the accepted faults' tracking (track.h). */
static const cfdi_diag_tables diag = {{
    .hyp = {{ {H}, {g["d"]}, {t.p}, hyp_kind, hyp_index, hyp_n_params, hyp_full,
             hyp_name_key, hyp_twins, hyp_penalty }},
    .settings = {{ {_int64(st.max_samples)}, {_real(st.isolation_margin)},
                  {_real(st.settle_rel_std)}, {_real(st.settle_noise)},
                  {_real(st.max_fit_variance)} }},
    .min_samples = {_int64(st.min_samples)}, .columns = diag_columns,
    .Gz = diag_Gz, .Gu = diag_Gu, .gamma = diag_gamma, .units = diag_units,
    .prior_precision = {_real(st.prior_precision)},
    .onset_before = {st.onset_before}, .max_onsets = {st.max_onsets},
    .max_earlier = {g["max_earlier"]}, .lookback = {g["lookback"]},
    .earlier_lookback = {g["earlier_lookback"]},
    .lagged = {{ {S1 - 1}, {t.q}, {m}, {len(lg["cols"])}, lag_cols, lag_hyp_cols,
                {len(lg["pairs"])}, lag_pairs, lag_hyp_pairs, lag_noise, lag_steady }},
    .track = {{ {t.p}, {t.p + t.q}, {tk["max_params"]}, track_chi2, track_ratio, track_unit,
               {_real(tk["precise"])}, {_int64(tk["first_check"])} }},
    .own_chi2 = {{ {own} }},
    .twin_order = twin_order, .twin_ratio = twin_ratio
}};
""")
    return "".join(parts)


MAKEFILE = """\
# Generated by `canfdi codegen`: the drive's monitor, built for this host or a Cortex-M4F.
#   make host               native build ({real}): build/host/cfdi_run
#   make run-host LOG=FILE  run it over a candump -L .log or a Vector .asc, printing JSON
#   make cortex-m4f         arm-none-eabi-gcc, float32, newlib-nano, no allocation:
#                           build/cortex-m4f/cfdi_run.elf
#   make qemu LOG=FILE      run that image on qemu-system-arm -M mps2-an386 (semihosting)
#   make count LOG=FILE     the same under qemu -icount: the loop's instructions per sample
#   make size               flash, static RAM and the worst stack of the image
CC ?= cc
ARM_CC ?= arm-none-eabi-gcc
ARM_SIZE ?= arm-none-eabi-size
QEMU ?= qemu-system-arm
WARN = -std=c99 -Wall -Wextra -Werror -pedantic -ffp-contract=off
HOT = bank.c counter.c decide.c decode.c detect.c e2e.c gate.c info.c lagged.c track.c \\
  compensate.c diagnose.c drive.c
# what runs once, at an event or at a heartbeat: built for size on the MCU
COLD = drive_init.c announce.c decisions.c track_check.c encode.c cfdi_tables.c cfdi_run.c
CORE = $(HOT) $(COLD)
HEADERS = cfdi.h decode.h e2e.h encode.h drive.h drive_impl.h lagged.h track.h cfdi_io.h \\
  cfdi_tables.h
M4F = -mcpu=cortex-m4 -mthumb -mfpu=fpv4-sp-d16 -mfloat-abi=hard
BUILD = build/cortex-m4f
ELF = $(BUILD)/cfdi_run.elf
LOGS = a candump -L .log or a Vector .asc

.PHONY: host run-host cortex-m4f qemu count size clean
host: build/host/cfdi_run

build/host/cfdi_run: $(CORE) cfdi_io_host.c $(HEADERS)
\tmkdir -p build/host
\t$(CC) $(WARN) -O2 {define} $(CFLAGS) -o $@ $(CORE) cfdi_io_host.c -lm

run-host: build/host/cfdi_run
\t@test -n "$(LOG)" || (echo "make run-host LOG=FILE ($(LOGS))" >&2; exit 2)
\t@build/host/cfdi_run "$(LOG)"

cortex-m4f: $(ELF)

# One link-time optimised unit (its stack usage and call graph its own: lto-ltrans0.ltrans.su,
# .ci; stack.awk walks the graphs for `make size`). The
# semihosting's bkpt needs GNU asm: the two I/O files are compiled as gnu99.
M4F_C = $(ARM_CC) $(WARN) $(M4F) -DCFDI_FLOAT32 $(EXTRA) -flto -ffunction-sections \\
  -fdata-sections -I$(CURDIR)
$(ELF): $(CORE) cfdi_io_semihost.c m4f_startup.c m4f.ld $(HEADERS)
\tmkdir -p $(BUILD)
\tcd $(BUILD) && for f in $(HOT); do $(M4F_C) -O2 -c $(CURDIR)/$$f || exit 1; done
\tcd $(BUILD) && for f in $(COLD); do $(M4F_C) -Os -c $(CURDIR)/$$f || exit 1; done
\tcd $(BUILD) && for f in cfdi_io_semihost.c m4f_startup.c; do \\
\t  $(ARM_CC) -std=gnu99 -Wall -Wextra -Werror $(M4F) -O2 -ffunction-sections \\
\t    -fdata-sections -fstack-usage -fcallgraph-info=su -I$(CURDIR) -c $(CURDIR)/$$f \\
\t    || exit 1; done
\t$(ARM_CC) $(M4F) -O2 -flto -flto-partition=one -fstack-usage -fcallgraph-info=su \\
\t  -dumpdir $(BUILD)/lto- \\
\t  -specs=nano.specs -nostartfiles -Wl,--gc-sections -T m4f.ld \\
\t  -Wl,-Map=$(BUILD)/cfdi_run.map -o $@ $(BUILD)/*.o -lm

QEMU_RUN = $(QEMU) -M mps2-an386 -nographic -monitor none -serial none \\
  -chardev stdio,id=semihost -semihosting-config enable=on,target=native,chardev=semihost
qemu: $(ELF)
\t@test -n "$(LOG)" || (echo "make qemu LOG=FILE ($(LOGS))" >&2; exit 2)
\t@$(QEMU_RUN),arg=cfdi_run,arg="$(LOG)" -kernel $(ELF)

# The same image counting its instructions: qemu -icount shift=0 runs one instruction per
# virtual nanosecond, and the board's SysTick ticks at 25 MHz: 40 instructions a tick.
count:
\t@test -n "$(LOG)" || (echo "make count LOG=FILE ($(LOGS))" >&2; exit 2)
\t@$(MAKE) -s cortex-m4f BUILD=build/cortex-m4f-count EXTRA=-DCFDI_TICK_INSNS=40
\t@$(QEMU_RUN),arg=cfdi_run,arg="$(LOG)" -icount shift=0 \\
\t  -kernel build/cortex-m4f-count/cfdi_run.elf

size: $(ELF)
\t@$(ARM_SIZE) -A $(ELF) | awk '/^\\.(text|ARM.exidx)/ {{f += $$2}} \\
\t  /^\\.data/ {{f += $$2; r += $$2}} /^\\.bss/ {{r += $$2}} \\
\t  END {{printf "flash %d bytes\\nstatic RAM %d bytes\\n", f, r}}'
\t@cat $(BUILD)/*.su | sort -t'\t' -k2 -n -r | awk -F'\t' \\
\t  'NR == 1 {{printf "largest stack frame %d bytes (%s)\\n", $$2, $$1}}'
\t@awk -v roots="cfdi_reset cfdi_drive_on_frame" -f stack.awk $(BUILD)/*.ci

clean:
\trm -rf build
"""


PROJECT_README = """\
# {name}: canfdi's drive monitor in C

Generated by `canfdi codegen` from {config_name} ({real}). The C core (the files canfdi's own
extension compiles) and this drive's tables as const data (`cfdi_tables.c`: data, never
logic; generate again rather than edit). `make host`, `make run-host LOG=FILE`, `make
cortex-m4f`, `make qemu LOG=FILE`, `make count LOG=FILE` and `make size`: see the Makefile.

## The integration API

```c
#include "cfdi_tables.h"

static uint64_t memory[(CFDI_GEN_MEMORY + 7) / 8]; /* the drive's: CFDI_GEN_MEMORY bytes */
static cfdi_drive drive;

void can_send(uint32_t id, int extended, const uint8_t *data, uint8_t len); /* your driver */

/* Once, at start: the tables checked, the memory laid out (CFDI_OK). */
int monitor_start(void)
{{
    return cfdi_drive_init(&drive, &cfdi_drive_tables_gen, memory, sizeof memory);
}}

static void send_pending(void)
{{
    cfdi_tx_frame tx;
    while (cfdi_drive_poll_tx(&drive, &tx) == 1) {{
        can_send(tx.id, tx.extended, tx.data, tx.len);
    }}
}}

/* Every received CAN frame: its ID, payload length, flags (CFDI_FLAG_*), payload and time
 * (ns); then what the monitor has to send, on the bus. */
void monitor_on_frame(uint32_t id, uint8_t len, uint8_t flags, const uint8_t *data,
                      int64_t t_ns)
{{
    cfdi_drive_on_frame(&drive, id, len, flags, data, t_ns); /* its status, >= 0 */
    send_pending();
}}

/* Every {period} s (a timer): the heartbeat, FDI_STATUS. */
void monitor_tick(void)
{{
    cfdi_drive_status(&drive);
    send_pending();
}}
```

`cfdi_drive_finish(&drive)` closes a pending sample at the end of a stream (a replayed log).
`cfdi_drive_poll_event(&drive, &event)` hands over what the monitor concluded, oldest first
(`cfdi_event`: a detection, a fault named, accepted or refined with its estimates and
variances, an alarm unexplained), for a firmware that acts on it; events not polled are
dropped after `CFDI_EVENT_QUEUE` and counted (`drive.events_dropped`).

What the monitor sends, as canfdi's monitor does: at an alarm {fault} (ID {fault_id}, state
detected, the alarm's sample); then the diagnosis, every fault hypothesis fitted by least
squares at every onset tried ({lookback} samples before the alarm are kept) and decided on at
each sample as canfdi's diagnoser decides: a fault named ({fault}, state named, and its
offset or bias in FDI_ESTIMATE with its standard deviation), accepted ({fault}, state
accepted, each estimate and its standard deviation in FDI_ESTIMATE), or the alarm left
unexplained. An accepted fault is compensated from its onset on, the window rebuilt and the
detector restarted, so the next fault is diagnosed on top of it; a diagnosis that finds what
an earlier estimate left refines it (FDI_ESTIMATE alone), and the accepted faults go on being
fitted between diagnoses, their significant corrections sent the same way. Nothing is sent by
a listen-only drive (`bus.transmit: false`).

## The memory it needs

`CFDI_GEN_MEMORY` = {total} bytes ({real}) in one block the caller owns, 8-byte aligned,
laid out by `cfdi_drive_init`, and `sizeof(cfdi_drive)` for the drive's state (its queues of
{frames} frames to send and `CFDI_EVENT_QUEUE` events, the compensation); the tables are const
(flash: `make size`). Its parts:

| what | bytes |
|---|---|
{memory}

No allocation, no global state in the core: everything is in the memory above, the caller's.
`make size` prints the image's flash, static RAM, its largest stack frame and its worst stack
(the deepest call chain in gcc's call graphs, from the reset handler and from
`cfdi_drive_on_frame`, the C library's few functions not counted); `make qemu` says on
stderr how deep the stack went in that run (measured: the free RAM painted at reset).
"""


def memory_parts(t: DriveTables, float32: bool) -> list[tuple[str, int]]:
    """The parts of a drive's memory block and their bytes (drive.c's carve, in its order)."""
    z = memory_sizes(t, float32)
    R = 4 if float32 else 8

    def a8(n: int) -> int:
        return (n + 7) // 8 * 8

    W, VW, S, M, P, X, L = (z[k] for k in ("W", "VW", "S", "M", "P", "X", "L"))
    parts = [("the frame's fields, the clock's pending sample, the samples one frame gives",
              a8(8 * VW) + a8(R * W) + a8(8 * W) + a8(16 * W)),
             ("the residual bank's window", a8(R * (S + 1) * W)),
             ("the residuals and the detectors' statistics",
              4 * a8(R * M) + a8(R * 2 * M) + a8(16 * M) + a8(M)),
             (f"the frames to send ({X})", a8(X * (6 + L))),
             ("each channel's compensation", a8((32 + 8 * R) * W))]
    if t.diag is not None:
        H, D, K, Rw, Y, NC, NP, T = (z[k] for k in ("H", "D", "K", "R", "Y", "NC", "NP", "T"))
        Q = W - P
        work = ((3 * M + 2 * D + 1) * D + (S + 1) * P + H * (2 * D * D + D) + 3 * M * NC
                + 2 * NC * NC + NC + (2 * NC * NC + NC) // 4 + 1)
        lend = 2 * S * Q * D + M * max(NC, D) + 2 * M + D
        track_item, correction = 16 + 4 * R, 8 + 4 * R
        parts += [(f"the samples kept ({Rw} rows) and the history ({Y})",
                   a8(R * (Rw + Y) * W)),
                  ("a kept sample's window and commands; the sums' scratch",
                   a8(R * (S + 1) * (W + P)) + a8(R * (max(work, lend) + 3 * D * D + 2 * D))),
                  (f"the fits: {H} hypotheses at {K} onsets (information, sandwich, vector "
                   "and cost; the tracking's scratch between diagnoses)",
                   a8(8 * K) + a8(R * max(H * K * (2 * D * D + D + 1),
                                          2 * M * T + M + 6 * T * T + 4 * T))),
                  ("the decision's", a8(R * (2 * P + H)) + a8(8 * D) + 2 * a8(8 * H) + a8(H)
                   + a8(4 * H)),
                  ("the events' lagged middles (their squares, by onset)",
                   a8(R * (S + 1) * Q * NC) + a8(R * K * NP) + a8(R * NP)),
                  (f"the accepted faults' tracking ({T} parameters)",
                   a8(track_item * T) + a8(correction * T) + a8(R * (4 * T * T + 2 * T + P)))]
    return parts


def project_readme(t: DriveTables, config_name: str, float32: bool) -> str:
    """The generated project's README: the integration API and the memory each part needs,
    in this drive's sizes."""
    parts = memory_parts(t, float32)
    fault = t.messages.get("FDI_FAULT")
    return PROJECT_README.format(
        name=t.name, config_name=config_name, real="float32" if float32 else "float64",
        memory="\n".join(f"| {what} | {n} |" for what, n in parts),
        total=sum(n for _, n in parts), frames=t.tx_frames,
        lookback=t.diag["lookback"] if t.diag is not None else 0,
        period=f"{t.status_period:g}",
        fault="FDI_FAULT" if fault is not None else "(listen-only: no) FDI_FAULT",
        fault_id=f"0x{fault.tables.frame_id:X}" if fault is not None else "none")


def write_project(config: MonitorConfig, doc: dict, out: Path, config_name: str,
                  float32: bool = False) -> list[Path]:
    """Write the project into ``out`` (created): the core's files, the generated tables, the
    Makefile. Returns the files written.

    Raises
    ------
    CodegenRefused
        The config asks for what the C loop does not do.
    OSError
        ``out`` cannot be written.
    """
    tables = drive_tables(config, doc)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    core = resources.files("canfdi._c")
    for name in CORE_FILES:
        with resources.as_file(core / name) as src:
            shutil.copyfile(src, out / name)
        written.append(out / name)
    for name, text in render(tables, config_name).items():
        (out / name).write_text(text)
        written.append(out / name)
    make = MAKEFILE.format(real="float32" if float32 else "float64",
                           define="-DCFDI_FLOAT32" if float32 else "")
    (out / "Makefile").write_text(make)
    written.append(out / "Makefile")
    (out / "README.md").write_text(project_readme(tables, config_name, float32))
    written.append(out / "README.md")
    return written
