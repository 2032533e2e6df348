"""`canfdi bench`: how fast the monitor is, against the bus it must keep up with."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from canfdi.cli.common import DEFAULT_CONFIG_DIR, config_error, load_config_or_exit

HELP = """\
Measure, on this machine and in one run, side by side:
  bus limit        frames/s of a saturated 1 Mbit/s classic CAN bus for the DBC's frame sizes,
                   without and with worst-case bit stuffing (computed)
  throughput       frames/s through decode -> assemble -> diagnose -> record (MCAP), fed from
                   memory in blocks, its ratio to the bus limit, CPU seconds per 10^6 frames;
                   and frames/s the service consumes from python-can's virtual bus
  decode           the precompiled vectorised decoder against cantools Message.decode
  capture          canfdi capture's path (arrays, assembly, MCAP) against python-can's
                   can.Logger writing BLF, on the same frames (best of three, interleaved)
  replay           samples/s of canfdi replay's block path over a long capture log (frames
                   and samples), and over the monitor log of the throughput run
  latency          p50/p99 from a frame's arrival to the end of its handling (fault frames
                   sent) in the live service, at 50% bus load (frames stamped on arrival: a
                   grid clock, which samples by time, then sees the drive's periods
                   compressed, and the figure is the handling time alone)
  memory           RSS growth over the throughput run, per 10^6 frames
The traffic is the emulator's drive on the config's bus (firmware_sim): a fault-free run of the
shipped scenario that plays that bus (its bus profile's DBC, as many drives), and for the
latency the same bus with faults; --scenario names another. So `--config
deploy/config/dc_motor_cia402.yaml` measures the CiA 402 bus, and so on for each profile.
--json prints one object. --quick runs ~10x fewer frames (a smoke test). Progress on stderr.

--daemon-frames N runs instead a soak of the daemon: `canfdi run`'s path (python-can Messages
through the service, the monitor, the recorder rotating as `canfdi run --log-dir` does, every
--rotate-mib MiB) fed N frames as fast as it takes them (10^8 frames: about 15 minutes). The
traffic is 1024 s of the drive played over and over (its alive counters and CRCs carry on
across repeats). It reports the RSS after 2x10^6 frames of warm-up (or a fifth of the run),
its maximum and end against it, frames/s, the false alarms and frame counters, and reads back
every rotated segment as soon as it is closed (in a worker process, every chunk's CRC
checked), counting its frames, then deletes it: the disk holds about two segments. Exit
status 1 when a segment is unreadable or the segments do not hold every frame fed."""


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="measure throughput, latency, decode, capture, replay",
                       description=HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--quick", action="store_true", help="a short run (about 10^5 frames)")
    p.add_argument("--frames", type=int, metavar="N",
                   help="frames for the throughput run (default 10^6, 10^5 with --quick)")
    p.add_argument("--config", type=Path, default=DEFAULT_CONFIG_DIR / "dc_motor.yaml",
                   metavar="FILE", help="monitor config (default: the DC motor)")
    p.add_argument("--scenario", metavar="FILE",
                   help="scenario whose frames to use (YAML or shipped name; its faults are "
                        "dropped for the throughput run; default: the one playing the "
                        "config's bus)")
    p.add_argument("--daemon-frames", type=int, metavar="N",
                   help="run the daemon soak instead: N frames through `canfdi run`'s path, "
                        "RSS and every rotated segment checked (e.g. 100000000)")
    p.add_argument("--rotate-mib", type=float, default=64.0, metavar="MIB",
                   help="the soak's segment size (default 64)")


def run(args: argparse.Namespace) -> int:
    import os

    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    from canfdi.tools.bench import run_bench

    config = load_config_or_exit(args.config, "bench")
    if isinstance(config, int):
        return config
    frames = args.frames or (100_000 if args.quick else 1_000_000)
    if args.daemon_frames is not None and args.daemon_frames < 100_000:
        print("canfdi bench: --daemon-frames: at least 100000", file=sys.stderr)
        return 2
    if not args.rotate_mib > 0:
        print("canfdi bench: --rotate-mib: must be > 0", file=sys.stderr)
        return 2
    if frames < 1000:
        print("canfdi bench: --frames: at least 1000", file=sys.stderr)
        return 2
    from canfdi.tools.pairing import NoPairing, scenario_for, without_faults
    from firmware_sim.scenario import SCENARIO_DIR, ScenarioError, load_scenario

    try:
        if args.scenario is not None:
            faulty = load_scenario(args.scenario)
            scenario = without_faults(faulty)
        else:
            scenario = scenario_for(config, SCENARIO_DIR)
            faulty = scenario_for(config, SCENARIO_DIR, faults=True)
    except (NoPairing, ScenarioError) as exc:
        print(f"canfdi bench: {exc}", file=sys.stderr)
        return 2
    start = time.monotonic()

    def progress(msg: str) -> None:
        print(f"canfdi bench [{time.monotonic() - start:6.1f} s] {msg}", file=sys.stderr,
              flush=True)

    if args.daemon_frames is not None:
        return _soak(config, args, scenario, progress, start)
    try:
        result = run_bench(config, frames=frames, quick=args.quick, progress=progress,
                           scenario=scenario, faulty=faulty)
    except ValueError as exc:
        return config_error(exc, "bench")
    result["elapsed_s"] = time.monotonic() - start
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    r = result
    rows = [
        ("bus limit, 1 Mbit/s", f"{r['bus_limit_fps']:,.0f} frames/s "
                                f"({r['bus_limit_stuffed_fps']:,.0f} with worst-case stuffing)"),
        ("throughput (memory)", f"{r['throughput_fps']:,.0f} frames/s = "
                                f"{r['throughput_ratio']:.1f} x the bus "
                                f"({r['throughput_ratio_stuffed']:.1f} x stuffed), "
                                f"{r['cpu_s_per_1e6_frames']:.2f} CPU s per 10^6 frames"),
        ("throughput (virtual bus)", f"{r['virtual_bus_fps']:,.0f} frames/s"),
        ("decode", f"{r['decode_fps']:,.0f} frames/s vs cantools "
                   f"{r['cantools_decode_fps']:,.0f} = {r['decode_ratio_vs_cantools']:.0f} x"),
        ("capture", f"{r['capture_fps']:,.0f} frames/s vs python-can BLF "
                    f"{r['python_can_blf_fps']:,.0f} = {r['capture_ratio_vs_python_can']:.2f} x"),
        ("replay", f"{r['replay_samples_per_s']:,.0f} samples/s over a capture log, "
                   f"{r['replay_monitor_log_samples_per_s']:,.0f} over a monitor log"),
        ("latency at 50% load", f"p50 {r['latency_p50_ms']:.3f} ms, p99 "
                                f"{r['latency_p99_ms']:.3f} ms ({r['latency_blocks']} blocks, "
                                f"{r['latency_faults_diagnosed']} faults diagnosed)"),
        ("memory", f"{r['rss_growth_mib']:.2f} MiB RSS growth per 10^6 frames"),
    ]
    for name, value in rows:
        print(f"{name:<26}{value}")
    print(f"({r['frames']:,} frames of {r['scenario']}, {r['elapsed_s']:.0f} s)")
    return 0


def _soak(config, args: argparse.Namespace, scenario, progress, start: float) -> int:
    """``--daemon-frames``: the daemon soak, printed; 1 when its log does not check out."""
    from canfdi.tools.bench import run_daemon_soak

    try:
        r = run_daemon_soak(config, args.daemon_frames, round(args.rotate_mib * 2**20),
                            scenario=scenario, progress=progress)
    except ValueError as exc:
        return config_error(exc, "bench")
    r["elapsed_s"] = time.monotonic() - start
    lost = r["daemon_frames"] - r["daemon_messages_dropped"] - r["daemon_frames_in_segments"]
    failed = bool(r["daemon_unreadable_segments"]) or lost > 0
    if args.json:
        print(json.dumps(r, indent=2))
    else:
        stats = r["daemon_frame_stats"]
        invalid = {k: v for k, v in stats.get("invalid_by_reason", {}).items() if v}
        rows = [
            ("daemon soak", f"{r['daemon_frames']:,} frames in {r['daemon_seconds']:.0f} s = "
                            f"{r['daemon_fps']:,.0f} frames/s (the service alone "
                            f"{r['daemon_service_fps']:,.0f})"),
            ("RSS", f"{r['daemon_rss_start_mib']:.2f} MiB after "
                    f"{r['daemon_rss_warmup_frames']:,} frames, max "
                    f"{r['daemon_rss_max_growth_mib']:+.2f} MiB, end "
                    f"{r['daemon_rss_end_growth_mib']:+.2f} MiB"),
            ("log", f"{r['daemon_segments']} segments of {r['daemon_rotate_mib']:g} MiB read "
                    f"back: {r['daemon_frames_in_segments']:,} frames, "
                    f"{r['daemon_messages_dropped']} dropped, "
                    f"{len(r['daemon_unreadable_segments'])} unreadable"),
            ("diagnosis", f"{r['daemon_false_alarms']} false alarms, "
                          f"{r['daemon_samples']:,} samples, invalid frames {invalid or 0}, "
                          f"samples broken {stats.get('samples_broken', 0)}, "
                          f"missing {stats.get('samples_missing', 0)}"),
        ]
        for name, value in rows:
            print(f"{name:<26}{value}")
        print(f"({r['daemon_scenario']} played over and over, {r['elapsed_s']:.0f} s)")
        for name, why in r["daemon_unreadable_segments"].items():
            print(f"unreadable segment {name}: {why}")
    if failed:
        print(f"canfdi bench: the soak's log does not check out ({lost} frames missing from "
              f"the segments, {len(r['daemon_unreadable_segments'])} unreadable)",
              file=sys.stderr)
        return 1
    return 0
