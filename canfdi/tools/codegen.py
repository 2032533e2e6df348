"""`canfdi codegen`: a drive's monitor as a self-contained C project for its MCU.

The project is the C core's own files (canfdi/_c, the ones the daemon's extension compiles)
and the drive's tables as const data generated from its config: the signal table and E2E
profiles (canfdi.bus.ctables), the counter clock's and time gate's parameters, the residual
bank's FIR blocks, noise and Page-Hinkley thresholds, the diagnosis' hypotheses and settings
(canfdi.methods.parity). Tables, never logic: every number comes from the objects the Python
monitor runs with, so the two compute the same thing.

The drive loop in C (canfdi/_c/drive.c) detects and diagnoses its first fault: named,
accepted or the alarm unexplained, each announced by FDI_FAULT. What follows an acceptance
(compensation and reset for the next fault, the tracking of accepted faults), FDI_ESTIMATE
and FDI_STATUS are issue 43's next steps; until then the gateway takes over there.
"""

from __future__ import annotations

import math
import shutil
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from canfdi.bus.frames import STATUS_NAMES, VALID_STATUSES
from canfdi.core.settings import ConfigError, MonitorConfig

__all__ = ["CORE_FILES", "CodegenRefused", "DriveTables", "drive_tables", "render",
           "write_project"]

CORE_FILES = ("cfdi.h", "decode.h", "e2e.h", "encode.h", "drive.h", "bank.c", "counter.c",
              "decide.c", "decode.c", "detect.c", "e2e.c", "encode.c", "gate.c", "info.c",
              "drive.c", "cfdi_run.c",
              "cfdi_io.h",
              "cfdi_io_host.c", "cfdi_io_semihost.c", "m4f_startup.c", "m4f.ld")
"""The C core's files a project holds (canfdi/_c; not _kernel.c, the CPython face), with the
runner and its two I/O sides (host stdio, MCU semihosting) and the Cortex-M4F's startup and
memory map."""


class CodegenRefused(ConfigError):
    """The config asks for something the C drive loop does not do (field, what instead)."""


@dataclass(frozen=True)
class DriveTables:
    """Everything the generated tables hold, as arrays: the bus's (canfdi.bus.ctables), the
    clock's and gate's (SampleAssembler.c_params), the bank's and detectors'."""

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
    fault: object = None  # canfdi.bus.ctables.MessageTables of FDI_FAULT; None: listen-only
    fault_roles: tuple[float, ...] = ()  # a detection's FDI_FAULT values by encode.h role
    fault_states: tuple[float, ...] = (0.0, 0.0, 0.0)  # its State: detected, named, accepted
    fault_kinds: tuple[float, ...] = (0.0, 0.0, 0.0)  # its Kind: none, actuator, sensor
    diag: dict | None = None  # the diagnosis' (ParityDiagnoser.c_tables); None: none in C
    input_names: tuple[str, ...] = ()
    output_names: tuple[str, ...] = ()


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
        detection["diag"] = diag = {**diag, "lookback": min(LOOKBACK, diag["recent"])}
    if diag is not None and diag["d"] > MAX_FAULTS:
        raise CodegenRefused("signals.outputs", f"a joint fit of {diag['d']} sensors: the C "
                                                f"diagnosis takes {MAX_FAULTS} at most")
    fault, roles = _fault_message(monitor, drive)
    states, kinds = _fault_codes(monitor, drive)
    return DriveTables(name=drive.name, bus=tables, clock=drive.clock.c_params(),
                       p=len(config.inputs), q=len(config.outputs), fault=fault,
                       fault_roles=roles, fault_states=states, fault_kinds=kinds,
                       input_names=tuple(config.inputs), output_names=tuple(config.outputs),
                       **detection)


# FDI_FAULT's signals by the encode.h role the C loop fills them with.
_FAULT_ROLES = {"Kind": "KIND", "State": "STATE", "Drive": "DRIVE", "Index": "INDEX",
                "Sample": "SAMPLE"}


def _fault_message(monitor, drive) -> tuple[object, tuple[float, ...]]:
    """FDI_FAULT as the C loop encodes it (its tables) and the values a detection gives its
    signals (Monitor.fault_values: the sample's its own at run time); (None, ()) for a
    listen-only monitor, which sends nothing."""
    from canfdi.bus.ctables import ENCODE_H, message_tables
    from canfdi.core.records import FaultEvent

    frames = monitor.frames
    if not frames.transmit:
        return None, ()
    name = "FDI_FAULT"
    try:
        tables = message_tables(frames.layouts[name], frames.keys[name], frames.profile(name),
                                _FAULT_ROLES)
    except ValueError as exc:
        raise CodegenRefused("bus.monitor.dbc", str(exc)) from None
    values = monitor.fault_values(FaultEvent(kind="detected", sample=0, timestamp_ns=0), drive)
    roles = [0.0] * ENCODE_H["CFDI_N_ROLES"]
    for signal, role in _FAULT_ROLES.items():
        roles[ENCODE_H[f"CFDI_ROLE_{role}"]] = float(values[signal])
    return tables, tuple(roles)


MAX_FAULTS = 4
"""drive.h's CFDI_MAX_FAULTS: the members of a joint fit the C diagnosis accepts at once."""

LOOKBACK = 192
"""Samples a drive's diagnosis keeps before its alarm (the Python diagnoser keeps
identification.max_samples of them): a fault whose change point lies further back is fitted
from the oldest kept, so its onsets may differ. 192 keeps dc_motor's Cortex-M4F image, the
runner's buffers included, within 16 KiB of static RAM."""


def _fault_codes(monitor, drive) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """FDI_FAULT's State of a detection, a naming and an acceptance, and its Kind of none, an
    actuator and a sensor (Monitor.fault_values: one place)."""
    from canfdi.core.records import FaultEvent

    def values(kind: str, target: str | None) -> dict:
        return monitor.fault_values(FaultEvent(kind=kind, sample=0, timestamp_ns=0,
                                               target=target), drive)

    states = tuple(float(values(k, None)["State"]) for k in ("detected", "named", "accepted"))
    kinds = tuple(float(values("detected", t)["Kind"]) for t in (None, "actuator", "sensor"))
    return states, kinds


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


def render(t: DriveTables, config_name: str) -> dict[str, str]:
    """{file name: text} of the generated tables: cfdi_tables.h (sizes, declarations) and
    cfdi_tables.c (the const data)."""
    b = t.bus
    S1, _, m = t.coef.shape
    g = t.diag
    diag_defines = "" if g is None else (
        f"#define CFDI_GEN_H {len(g['table'].kind)}   /* fault hypotheses */\n"
        f"#define CFDI_GEN_D {g['d']}   /* parameters of a hypothesis, at most */\n"
        f"#define CFDI_GEN_K {g['settings'].max_onsets}   /* onsets a diagnosis tries */\n"
        f"#define CFDI_GEN_LOOKBACK {g['lookback']}   /* samples kept before an alarm */\n")
    header = f"""/* Generated by `canfdi codegen` from {config_name}: the tables of drive {t.name}.
 * Data, not logic; do not edit (generate again). */
#ifndef CFDI_TABLES_H
#define CFDI_TABLES_H

#include "drive.h"

#define CFDI_GEN_WIDTH {t.p + t.q}   /* a sample: p inputs, q outputs */
#define CFDI_GEN_VWIDTH {b.width}  /* the most fields a message gives */
#define CFDI_GEN_S {S1 - 1}        /* the residual bank's window, samples before */
#define CFDI_GEN_M {m}             /* residuals */
#define CFDI_GEN_P {t.p}             /* inputs */
#define CFDI_GEN_Q {t.q}             /* outputs */
{diag_defines}
extern const cfdi_drive_tables cfdi_drive_tables_gen;
extern const char *const cfdi_drive_name;
extern const char *const cfdi_status_names[CFDI_N_STATUS];
extern const uint8_t cfdi_status_valid[CFDI_N_STATUS];
extern const char *const cfdi_residual_names[CFDI_GEN_M];
extern const char *const cfdi_input_names[CFDI_GEN_P];
extern const char *const cfdi_output_names[CFDI_GEN_Q];

#endif
"""
    c = t.clock
    dest = np.asarray(c["dest"], dtype=np.int64)
    parts = [f"/* Generated by `canfdi codegen` from {config_name}: drive {t.name}. */\n"
             "#include <math.h>\n#include <stdint.h>\n\n#include \"cfdi_tables.h\"\n\n"]
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
    f = t.fault
    if f is not None:
        parts.append(_array("int32_t", "fault_e2e_spec", f.e2e_spec, str, 16))
        parts.append(_array("uint8_t", "fault_e2e_bytes", f.e2e_bytes, str, 16))
        parts.append(_array("int64_t", "fault_sig_int", f.sig_int, _int64))
        parts.append(_array("double", "fault_sig_real", f.sig_real, _real, 3))
        parts.append(f"""
/* FDI_FAULT, the frame announcing a detection (the monitor DBC's layout, its E2E). */
static const cfdi_message fault = {{
    {f.frame_id}u, {int(f.extended)}, {f.length},
    fault_e2e_spec, fault_e2e_bytes,
    fault_sig_int, fault_sig_real, {len(f.sig_int)}
}};
""")
    if g is not None:
        parts.append(_diag_tables(g, t.p))
    roles = ", ".join(_real(v) for v in (t.fault_roles or (0.0,)))
    parts.append(f"""
static const cfdi_bus bus = {{
    std_entry, ext_id, ext_entry, {len(b.ext_id)},
    entry, {len(b.entry)}, {b.n_slots},
    e2e_spec, e2e_bytes, {len(b.e2e_spec)},
    sig_int, sig_real, {len(b.sig_int)},
    ids_int, ids_real, {len(b.ids_int)},
    {b.width}
}};

const cfdi_drive_tables cfdi_drive_tables_gen = {{
    &bus,
    {_int64(c["gate_bound"])}, {_int64(c["gate_confirm"])},
    dest, {dest.shape[0]}, {dest.shape[1]},
    {_int64(c["mod"])}, {_real(c["dt_ns"])}, {_real(c["slack"])},
    {t.p}, {t.q},
    coef, uses, {S1 - 1}, {m},
    sigma, delta, h,
    {"&fault" if f is not None else "NULL"}, {{ {roles} }},
    {{ {", ".join(_real(v) for v in t.fault_states)} }},
    {{ {", ".join(_real(v) for v in t.fault_kinds)} }},
    {"&diag" if g is not None else "NULL"}
}};

const char *const cfdi_drive_name = {_string(t.name)};
const char *const cfdi_status_names[CFDI_N_STATUS] = {{
    {", ".join(_string(s) for s in STATUS_NAMES)}
}};
const uint8_t cfdi_status_valid[CFDI_N_STATUS] = {{
    {", ".join("1" if s in VALID_STATUSES else "0" for s in STATUS_NAMES)}
}};
const char *const cfdi_residual_names[CFDI_GEN_M] = {{
    {", ".join(_string(s) for s in t.residual_names)}
}};
const char *const cfdi_input_names[CFDI_GEN_P] = {{
    {", ".join(_string(s) for s in t.input_names)}
}};
const char *const cfdi_output_names[CFDI_GEN_Q] = {{
    {", ".join(_string(s) for s in t.output_names)}
}};
""")
    return {"cfdi_tables.h": header, "cfdi_tables.c": "".join(parts)}


def _diag_tables(g: dict, p: int) -> str:
    """The diagnosis' const data (drive.h's cfdi_diag_tables)."""
    table, st = g["table"], g["settings"]
    H = len(table.kind)
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
             _array("cfdi_real", "diag_units", g["units"], _real, 4)]
    parts.append(f"""
/* The diagnosis: its hypotheses, settings and what their fits are made of. */
static const cfdi_diag_tables diag = {{
    {{ {H}, {g["d"]}, {p}, hyp_kind, hyp_index, hyp_n_params, hyp_full, hyp_name_key,
      hyp_twins, hyp_penalty }},
    {{ {_int64(st.max_samples)}, {_real(st.isolation_margin)}, {_real(st.settle_rel_std)},
      {_real(st.settle_noise)}, {_real(st.max_fit_variance)} }},
    {_int64(st.min_samples)}, diag_columns, diag_Gz, diag_Gu, diag_gamma, diag_units,
    {_real(st.prior_precision)},
    {st.onset_before}, {st.max_onsets}, {g["lookback"]}
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
#   make size               flash, static RAM and stack frames of the image
CC ?= cc
ARM_CC ?= arm-none-eabi-gcc
ARM_SIZE ?= arm-none-eabi-size
QEMU ?= qemu-system-arm
WARN = -std=c99 -Wall -Wextra -Werror -pedantic -ffp-contract=off
CORE = bank.c counter.c decide.c decode.c detect.c e2e.c encode.c gate.c info.c drive.c \\
  cfdi_tables.c cfdi_run.c
HEADERS = cfdi.h decode.h e2e.h encode.h drive.h cfdi_io.h cfdi_tables.h
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

# (semihosting's bkpt needs GNU asm: the two I/O files are compiled as gnu99)
$(ELF): $(CORE) cfdi_io_semihost.c m4f_startup.c m4f.ld $(HEADERS)
\tmkdir -p $(BUILD)
\tcd $(BUILD) && for f in $(CORE); do \\
\t  $(ARM_CC) $(WARN) $(M4F) -O2 -DCFDI_FLOAT32 $(EXTRA) -ffunction-sections \\
\t    -fdata-sections -fstack-usage -I$(CURDIR) -c $(CURDIR)/$$f || exit 1; done
\tcd $(BUILD) && for f in cfdi_io_semihost.c m4f_startup.c; do \\
\t  $(ARM_CC) -std=gnu99 -Wall -Wextra -Werror $(M4F) -O2 -ffunction-sections \\
\t    -fdata-sections -fstack-usage -I$(CURDIR) -c $(CURDIR)/$$f || exit 1; done
\t$(ARM_CC) $(M4F) -specs=nano.specs -nostartfiles -Wl,--gc-sections -T m4f.ld \\
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
\t  'NR == 1 {{printf "largest stack frame %d bytes (%s)\\n", $$2, $$1}} {{s += $$2}} \\
\t   END {{printf "all stack frames together %d bytes (a bound on any call chain)\\n", s}}'

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

static double values[CFDI_GEN_VWIDTH], buffer[CFDI_GEN_WIDTH], samples[2 * CFDI_GEN_WIDTH];
static cfdi_real ring[(CFDI_GEN_S + 1) * CFDI_GEN_WIDTH], r[CFDI_GEN_M], ph[2 * CFDI_GEN_M];
static cfdi_real g_up[CFDI_GEN_M], g_down[CFDI_GEN_M];
static int64_t last_zero[2 * CFDI_GEN_M];
static int8_t alarm[CFDI_GEN_M];
/* the diagnosis' (H hypotheses, K onsets, D parameters) */
static cfdi_real recent[(CFDI_GEN_LOOKBACK + CFDI_GEN_S + 1) * CFDI_GEN_WIDTH];
static cfdi_real window[(CFDI_GEN_S + 1) * CFDI_GEN_WIDTH], U[(CFDI_GEN_S + 1) * CFDI_GEN_P];
static cfdi_real rn[CFDI_GEN_M], work[CFDI_INFO_WORK(CFDI_GEN_M, CFDI_GEN_D)];
static int64_t onsets[CFDI_GEN_K], best_onset[CFDI_GEN_H], order[CFDI_GEN_H];
static cfdi_real J[CFDI_GEN_H * CFDI_GEN_K * CFDI_GEN_D * CFDI_GEN_D];
static cfdi_real meat[CFDI_GEN_H * CFDI_GEN_K * CFDI_GEN_D * CFDI_GEN_D];
static cfdi_real P[CFDI_GEN_H * CFDI_GEN_K * CFDI_GEN_D * CFDI_GEN_D];
static cfdi_real h[CFDI_GEN_H * CFDI_GEN_K * CFDI_GEN_D];
static cfdi_real theta[CFDI_GEN_H * CFDI_GEN_K * CFDI_GEN_D];
static cfdi_real rr[CFDI_GEN_H * CFDI_GEN_K], cost[CFDI_GEN_H * CFDI_GEN_K];
static cfdi_real lu[CFDI_GEN_D * CFDI_GEN_D], u_abs[CFDI_GEN_P], n_u[CFDI_GEN_P];
static cfdi_real cost_h[CFDI_GEN_H];
static size_t perm[CFDI_GEN_D];
static uint8_t near[CFDI_GEN_H];
static int32_t leftover[CFDI_GEN_H];
static cfdi_drive drive;
static const cfdi_drive_memory mem = {{values, buffer, samples, ring, r, ph, last_zero, g_up,
                                      g_down, alarm,
                                      {{recent, window, U, rn, onsets, J, meat, P, h, theta,
                                       rr, cost, lu, perm, work, u_abs, n_u, best_onset, order,
                                       cost_h, near, leftover}}}};

void can_send(uint32_t id, int extended, const uint8_t *data, uint8_t len); /* your driver */

/* Once, at start: the tables and the memory checked against each other (CFDI_OK). */
int monitor_start(void)
{{
    return cfdi_drive_init(&drive, &cfdi_drive_tables_gen, &mem);
}}

/* Every received CAN frame: its ID, payload length, flags (CFDI_FLAG_*), payload and time
 * (ns); then what the monitor has to send, on the bus. */
void monitor_on_frame(uint32_t id, uint8_t len, uint8_t flags, const uint8_t *data,
                      int64_t t_ns)
{{
    cfdi_tx_frame tx;
    cfdi_drive_on_frame(&drive, id, len, flags, data, t_ns); /* its status, >= 0 */
    while (cfdi_drive_poll_tx(&drive, &tx) == 1) {{
        can_send(tx.id, tx.extended, tx.data, tx.len);
    }}
}}
```

`cfdi_drive_finish(&drive)` closes a pending sample at the end of a stream (a replayed log).
After the first alarm `drive.alarmed` is 1, `drive.alarm_k` its sample and
`drive.alarm_onset` the change point it dates; the monitor then sends a {fault} frame
(ID {fault_id}, state detected, the alarm's sample, its E2E), as canfdi's monitor does.
The alarm starts a diagnosis: every fault hypothesis fitted by least squares at every onset
tried, from the change point on ({lookback} samples before the alarm are kept), and decided
on at each sample as canfdi's diagnoser decides. Its decisions, `drive.events[0 ..
drive.n_events - 1]` (a fault named, accepted, or the alarm unexplained), are announced the
same way, state named or accepted, with the channel. What follows an acceptance
(compensation, the next fault) and the estimates' FDI_ESTIMATE frames are still the
gateway's (canfdi issue 43): the loop diagnoses its first fault.

## The memory each part needs

| what | elements | bytes |
|---|---|---|
{memory}
| `cfdi_drive` (state; a queue of `CFDI_TX_QUEUE` frames to send) | 1 | `sizeof(cfdi_drive)` |
| the tables (const: flash) | | `make size` |

No allocation, no global state in the core: everything is in the memory above, the caller's.
`make size` prints the image's flash, static RAM and its largest stack frame.
"""


def project_readme(t: DriveTables, config_name: str, float32: bool) -> str:
    """The generated project's README: the integration API and the memory each part needs,
    in this drive's sizes."""
    S1, _, m = t.coef.shape
    width, vwidth = t.p + t.q, t.bus.width
    real = 4 if float32 else 8
    rows = [("`values` (double: one frame's fields)", vwidth, 8),
            ("`buffer` (double: the clock's pending sample)", width, 8),
            ("`samples` (double: the samples one frame delivers)", 2 * width, 8),
            ("`ring` (cfdi_real: the residual bank's window)", S1 * width, real),
            ("`r`, `g_up`, `g_down` (cfdi_real: residuals, statistics)", 3 * m, real),
            ("`ph` (cfdi_real: the statistics g+ and g-)", 2 * m, real),
            ("`last_zero` (int64_t)", 2 * m, 8),
            ("`alarm` (int8_t)", m, 1)]
    g = t.diag
    if g is not None:
        H, d, K, p = len(g["table"].kind), g["d"], g["settings"].max_onsets, t.p
        rows += [("`recent` (cfdi_real: the samples kept before an alarm)",
                  (g["lookback"] + S1) * width, real),
                 ("`window`, `U`, `rn`, `work` (cfdi_real: one kept sample's)",
                  S1 * width + S1 * p + m + (3 * m + 2 * d + 1) * d, real),
                 ("`J`, `meat`, `P` (cfdi_real: every fit's information, sandwich, inverse)",
                  3 * H * K * d * d, real),
                 ("`h`, `theta`, `rr`, `cost` (cfdi_real: every fit's)",
                  2 * H * K * d + 2 * H * K, real),
                 ("`lu`, `u_abs`, `n_u`, `cost_h` (cfdi_real)", d * d + 2 * p + H, real),
                 ("`onsets`, `best_onset`, `order` (int64_t)", K + 2 * H, 8),
                 ("`perm` (size_t: 8 bytes at most)", d, 8), ("`near` (uint8_t)", H, 1),
                 ("`leftover` (int32_t)", H, 4)]
    memory = "\n".join(f"| {what} | {n} | {n * size} |" for what, n, size in rows)
    memory += f"\n| all of the above | | {sum(n * size for _, n, size in rows)} |"
    fault = t.fault
    return PROJECT_README.format(
        name=t.name, config_name=config_name, real="float32" if float32 else "float64",
        memory=memory, lookback=g["lookback"] if g is not None else 0,
        fault="FDI_FAULT" if fault is not None else "(listen-only: no)",
        fault_id=f"0x{fault.frame_id:X}" if fault is not None else "none")


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
