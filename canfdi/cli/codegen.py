"""`canfdi codegen CONFIG -o DIR [--float32]`: the drive's monitor as a C project for its MCU."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from canfdi.cli.common import config_error, load_config_or_exit

HELP = """\
Write a self-contained C99 project that runs the drive's monitor on its own MCU: the C core
(the same files canfdi's extension compiles: decode and E2E, the time gate, the counter clock,
the residual bank, the Page-Hinkley detectors, the parity diagnoser and the drive loop) and
the drive's tables as const data generated from the config (its signal table and E2E
profiles, the clock and gate, the bank's FIR blocks, noise and thresholds, the hypotheses and
identification settings, the monitor's FDI_FAULT, FDI_ESTIMATE and FDI_STATUS frames), a
README of the integration API (init, on_frame, poll_tx for the frames to send, status for the
heartbeat, poll_event, the memory each part needs) and a Makefile:

  make host                 a native build (float64; float32 with --float32)
  make run-host LOG=FILE    run it over a candump -L .log or a Vector .asc (CAN and CAN FD):
                            the JSON `canfdi replay --json` prints (faults, named,
                            unexplained, refined, detections, samples, frame counters), and
                            the frames sent
  make cortex-m4f           arm-none-eabi-gcc, float32, newlib-nano, no allocation
  make qemu LOG=FILE        that image on qemu-system-arm -M mps2-an386, semihosting
  make count LOG=FILE       the same under qemu -icount: the loop's instructions per sample
                            and in its costliest frame
  make size                 the image's flash, static RAM and worst stack
The Cortex-M4F targets need Debian's gcc-arm-none-eabi, libnewlib-arm-none-eabi and
qemu-system-arm (in a clone of canfdi, deploy/install-mcu-toolchain installs them as root).

The C loop detects and diagnoses every fault as canfdi's parity diagnoser does: each alarm
dated by its change point, every hypothesis fitted at every onset tried, then named,
accepted, or the alarm unexplained; an accepted fault compensated, the window rebuilt and
the detector restarted for the next; what an estimate left refined; the accepted faults
tracked between diagnoses. It says so on the bus as canfdi's monitor does (FDI_FAULT,
FDI_ESTIMATE; FDI_STATUS when the caller's timer asks; nothing when bus.transmit is false).
The samples a diagnosis fits from before its alarm live in the MCU's RAM:
identification.lookback (with channels compensated) and onset_before set how many.
A config the C loop cannot run is refused with one line naming the field: a method with no
C tables (of the built-ins only parity has them), several drives, a trigger or grid clock,
signature CUSUMs, the noise watchdog asked for (it stays on the gateway: leave its section
out or set watchdog.enabled: false), teach-in, a monitor DBC whose frames it cannot encode
(multiplexed, 16-bit floats).

Exit status: 0 written, 2 a bad or refused config (the field named), 1 the project could not
be written."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("codegen", help="the drive's monitor as a C project for its MCU",
                       description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("config", type=Path, help="monitor config (YAML), e.g. "
                                             "deploy/config/dc_motor.yaml")
    p.add_argument("-o", "--output", type=Path, required=True, metavar="DIR",
                   help="the project's folder (created; files of the same names replaced)")
    p.add_argument("--float32", action="store_true",
                   help="the host build in float32, as the MCU's FPU computes")


def run(args: argparse.Namespace) -> int:
    from canfdi.config import ConfigError, read_yaml
    from canfdi.tools.codegen import write_project
    from canfdi.tools.session import remember_designs

    remember_designs()  # the thresholds' calibration, kept as `canfdi run` keeps it

    config = load_config_or_exit(args.config, "codegen")
    if isinstance(config, int):
        return config
    try:
        doc = read_yaml(Path(args.config), ConfigError, "config")
        written = write_project(config, doc if isinstance(doc, dict) else {}, args.output,
                                Path(args.config).name, float32=args.float32)
    except ConfigError as exc:
        return config_error(exc, "codegen")
    except OSError as exc:
        print(f"canfdi codegen: {args.output}: cannot write ({exc.strerror or exc})",
              file=sys.stderr)
        return 1
    print(f"canfdi codegen: wrote {len(written)} files to {args.output} "
          f"(make -C {args.output} host)", file=sys.stderr)
    return 0
