"""The monitor without I/O: frames in; samples, diagnoses, fault frames and log records out.

`canfdi run`, `demo`, `capture` and `replay` all drive one Monitor: the live verbs from the
asyncio service, replay from a log. Nothing here reads a clock, a bus or a file: timestamps come
with the frames, frames to send are returned, records go to an optional sink (the MCAP recorder).

    frame -> which drive (its IDs) -> that drive's sample clock (E2E checks, counters, gaps)
          -> Sample -> that drive's Diagnoser.update -> FaultEvents (with the drive's name)
          -> FDI_FAULT / FDI_ESTIMATE frames (with the drive's index), unless listen-only

Each drive's diagnoser is the method's run by a `Supervisor` (canfdi.core.protocol), which says
the drive's state: the noise watchdog wrapping it (canfdi.core.watched), teach-in standing in
for it until it has learned (canfdi.core.teachin), or nothing (canfdi.core.supervision). The
monitor only routes: samples to the drive's diagnoser, its events to the sink and the bus.

Several drives of one description share a bus (the config's ``drives:``, docs/bus.md): each
has its own sample clock and diagnoser; a frame goes to the drive whose message it is (to each
drive that maps it, for a message they share, such as the CANopen SYNC that triggers them all),
and a frame of no drive (the monitor's own, other nodes, unknown IDs) to the first, which only
counts it.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, replace
from functools import partial
from typing import Any, Protocol

import numpy as np

from canfdi import __version__, methods
from canfdi.bus.assembler import SampleAssembler
from canfdi.bus.clock import LatestValueClock, make_clock
from canfdi.bus.dbc import BusMap, MessageKey, keys_of, load_dbc, message_key
from canfdi.bus.frames import (
    FLAG_EXTENDED,
    STATUS_CODES,
    STATUS_NAMES,
    FrameBlock,
    frame_counters,
)
from canfdi.bus.monitorframes import MonitorFrames
from canfdi.core import kernel as kernels
from canfdi.core.eventtext import event_level, event_line
from canfdi.core.kernel import Kernel
from canfdi.core.protocol import Diagnoser, Supervisor
from canfdi.core.records import BlockResult, FaultEvent, Sample
from canfdi.core.settings import MonitorConfig
from canfdi.core.supervision import Supervision
from canfdi.core.teachin import Teacher, TeachIn
from canfdi.core.watched import NoiseWatched

__all__ = ["Drive", "Monitor", "OutFrame", "RecordSink", "Teacher", "summary_json"]


_KIND = {"actuator": 1, "sensor": 2}
_STATE = {"detected": 1, "named": 2, "accepted": 3}
_PARAM = {"eta": 0, "lambda": 1, "bias": 2}
STD_PARAM = 3
"""FDI_ESTIMATE's Param of an estimate's standard deviation: its estimate's plus this."""
_STATUS = {"starting": 0, "monitoring": 1, "diagnosing": 2, "degraded": 3, "bus_error": 4,
           "teaching": 5, "mismatch": 6, "no_traffic": 7, "checking": 8, "quiet": 9,
           "named": 10}

MONITOR_ROLES = {
    "FDI_FAULT": {"Kind": "KIND", "State": "STATE", "Drive": "DRIVE", "Index": "INDEX",
                  "Sample": "SAMPLE"},
    "FDI_ESTIMATE": {"Kind": "KIND", "Param": "PARAM", "Drive": "DRIVE", "Index": "INDEX",
                     "Value": "VALUE"},
    "FDI_STATUS": {"State": "STATE", "Drive": "DRIVE", "ActiveFaults": "ACTIVE",
                   "Samples": "SAMPLE", "InvalidFrames": "INVALID"},
}
"""Each monitor message's signals by what they carry (canfdi/_c/encode.h's CFDI_ROLE_*): the
values `fault_values`, `estimate_values` and `status_values` give them, which `canfdi codegen`'s
C loop fills in the same way."""

WRAPS = {"FDI_FAULT": {"Sample": 1 << 32},
         "FDI_STATUS": {"Samples": 1 << 21, "InvalidFrames": 1 << 16}}
"""Counts a monitor message carries modulo its field (the rest are clipped to the DBC's range,
as the codec clips); `canfdi codegen` writes these moduli for the C loop."""

CAPS = {"FDI_STATUS": {"ActiveFaults": 15}}
"""Counts a monitor message carries at most this large."""


def _bounded(message: str, values: dict[str, int]) -> dict[str, int]:
    """A monitor message's counts taken modulo `WRAPS` and capped by `CAPS`."""
    out = dict(values)
    for name, modulus in WRAPS.get(message, {}).items():
        out[name] = out[name] % modulus
    for name, cap in CAPS.get(message, {}).items():
        out[name] = min(out[name], cap)
    return out


class RecordSink(Protocol):
    """Where the monitor's records go (canfdi.io.writer.McapRecorder fits)."""

    def write_frame(self, timestamp_ns: int, frame_id: int, data: bytes, status: str,
                    extended: bool = False) -> None: ...
    def write_sample(self, sample: Sample, input_names: list[str],
                     output_names: list[str], drive: str | None = None) -> None: ...
    def write_residuals(self, timestamp_ns: int, k: int, names: list[str], r: np.ndarray,
                        normalized: np.ndarray, statistic: np.ndarray,
                        drive: str | None = None) -> None: ...
    def write_event(self, event: FaultEvent) -> None: ...
    def write_status(self, timestamp_ns: int, state: str, samples: int,
                     frames: Mapping[str, Any], active_faults: int) -> None: ...
    def write_frames(self, block: FrameBlock, statuses: np.ndarray,
                     status_names: tuple[str, ...]) -> None: ...
    def write_samples(self, k: np.ndarray, t_ns: np.ndarray, U: np.ndarray, Z: np.ndarray,
                      gap: np.ndarray, input_names: list[str], output_names: list[str],
                      drive: str | None = None) -> None: ...
    def write_residual_rows(self, k: np.ndarray, t_ns: np.ndarray, names: list[str],
                            R: np.ndarray, Rn: np.ndarray, stat: np.ndarray,
                            drive: str | None = None) -> None: ...
    def write_metadata(self, name: str, values: dict[str, str]) -> None: ...
    def write_log(self, timestamp_ns: int, level: str, message: str, name: str) -> None: ...


@dataclass(frozen=True)
class OutFrame:
    """A frame the monitor wants on the bus."""

    frame_id: int
    data: bytes
    extended: bool = False


@dataclass
class Drive:
    """One drive on the bus: its name, its index in ``drives:`` (the Drive signal of the
    monitor's frames), its bus map, its sample clock, its diagnoser (a `Supervisor`; None when
    capturing) and how many samples it has delivered."""

    name: str
    index: int
    bus_map: BusMap
    clock: SampleAssembler | LatestValueClock
    diagnoser: Supervisor | None
    samples: int = 0

    @property
    def state(self) -> str:
        """"teaching", "checking", "diagnosing", "named", "mismatch", "quiet" or "monitoring"
        (FDI_STATUS's State names; canfdi.core.protocol.STATES)."""
        return "monitoring" if self.diagnoser is None else self.diagnoser.state


class Monitor:
    """Frames to diagnoses for one config (one or several drives).

    Parameters
    ----------
    config : the monitor config (bus.dbc must name the drive's DBC).
    sink : optional record sink (MCAP recorder).
    record_residuals : write every sample's residuals to the sink (the bulk of a log).
    diagnose : False for capture: decode and record, no diagnosis (and no calibration).
    teach : teach-in: each drive's first ``teach.samples`` samples are recorded, not
        diagnosed (FDI_STATUS "teaching"); then ``teach.learn`` gives the drive its diagnoser
        and the learned values go to the log's metadata ("canfdi.teach.<drive>") and
        ``self.taught``.
    kernel : the kernel the frame decode and the diagnosers' block forms run on
        (canfdi.core.kernel); by default the one a command would run on (CANFDI_KERNEL, else
        c where built): a library caller and the command line give the same numbers.

    Raises
    ------
    ConfigError
        Whatever of the bus section the DBC contradicts (canfdi.bus.dbc, monitorframes).
    """

    def __init__(self, config: MonitorConfig, sink: RecordSink | None = None,
                 record_residuals: bool = True, diagnose: bool = True,
                 teach: Teacher | None = None, kernel: Kernel | None = None) -> None:
        self.config = config
        self.kernel = kernel or kernels.resolve()
        self.method = methods.get(config.method)
        self.dt = config.model.dt or 1.0
        if config.bus.dbc is None:
            from canfdi.core.settings import ConfigError

            raise ConfigError("bus.dbc", "a DBC file is needed to read the bus")
        database, label = load_dbc(config.bus.dbc, config.path)
        bus_keys = keys_of(database, config)
        self.frames = MonitorFrames.from_config(config, bus_keys)
        monitor = self.frames.known()
        self.teach = teach
        self.taught: dict[str, dict[str, str]] = {}
        self.drives: list[Drive] = []
        for index, drive in enumerate(config.drive_list):
            bus_map = BusMap.from_dbc(database, config, drive, label, monitor)
            clock = make_clock(bus_map, self.dt, config.bus.clock)
            self.kernel.install(bus_map=bus_map, gate=clock.gate, clock=clock)
            self.drives.append(Drive(drive.name, index, bus_map, clock,
                                     self._supervised(drive.name) if diagnose else None))
        # Which drives a frame goes to: (ID, extended) -> bit mask of drive indices. A message
        # several drives share (a CANopen SYNC that triggers all) goes to each; a frame of no
        # drive goes to the first, which only counts it.
        owners: dict[MessageKey, int] = {}
        for d in self.drives:
            for key in d.bus_map.keys:
                owners[key] = owners.get(key, 0) | (1 << d.index)
        self._owners_of = owners
        self._owner_keys = np.array(sorted(k[0] + (k[1] << 32) for k in owners), dtype=np.int64)
        self._owner_mask = np.array([owners[(int(v) & 0xFFFFFFFF, bool(v >> 32))]
                                     for v in self._owner_keys], dtype=np.int64)
        # Frame counters of the whole bus (a shared frame once), by status code.
        self._frame_counts = np.zeros(len(STATUS_NAMES), dtype=np.int64)
        self._steps_said: dict[str, int] = {}  # clock steps logged, per drive
        self.sink = sink
        self.record_residuals = record_residuals
        self.events: list[FaultEvent] = []
        self.first_timestamp_ns: int | None = None
        # The drive's time now: the time the latest frame carries (the bus's receive time
        # live, the emulated time in a demo). What the monitor's own records are stamped with.
        self.last_timestamp_ns: int | None = None

    def _supervised(self, name: str) -> Supervisor:
        """Drive ``name``'s diagnoser, the config's method's run as the config says: under
        the noise watchdog (armed after a check of the configured noise), or as it is; with
        teach-in, a stand-in until it has learned (the learned values to `_learned`), then
        the diagnoser learned under the watchdog (no check: its noise was just learned)."""
        cfg = self.config
        w = cfg.watchdog

        def run(dg: Diagnoser, check: bool) -> Supervisor:
            self.kernel.use_on(dg)
            if not w.enabled:
                return Supervision(dg)
            return NoiseWatched(dg, w.factor, w.block, w.blocks, check=check,
                                longest_diagnosis=cfg.identification.max_samples)

        configured = self.method.build(cfg)
        if self.teach is None:
            return run(configured, check=True)
        # (A bound method, not a lambda: a deep copy of the monitor reports to the copy.)
        return TeachIn(configured, self.teach, then=partial(run, check=False),
                       on_learned=partial(self._learned, name))

    def _learned(self, name: str, learned: dict[str, str]) -> None:
        """Teach-in of drive ``name`` is over: what it learned (or why not) to ``taught`` and
        the log's metadata."""
        self.taught[name] = learned
        if self.sink is not None:
            self.sink.write_metadata(f"canfdi.teach.{name}", learned)

    # -- the first (or only) drive, for the many callers that watch one --------------------
    @property
    def diagnoser(self) -> Diagnoser | None:
        """The first drive's method diagnoser (the one its supervisor runs now)."""
        supervisor = self.drives[0].diagnoser
        return None if supervisor is None else supervisor.diagnoser

    @property
    def assembler(self) -> SampleAssembler | LatestValueClock:
        """The first drive's sample clock."""
        return self.drives[0].clock

    @property
    def bus_map(self) -> BusMap:
        """The first drive's bus map."""
        return self.drives[0].bus_map

    @property
    def samples(self) -> int:
        """Samples delivered, every drive."""
        return sum(d.samples for d in self.drives)

    @property
    def frame_stats(self) -> dict:
        """Frame counters of the bus (a frame several drives share counted once) and sample
        counters of every drive's clock, summed."""
        if len(self.drives) == 1:
            return self.drives[0].clock.stats
        clocks = [d.clock.stats for d in self.drives]
        return frame_counters(self._frame_counts, *(sum(c[key] for c in clocks) for key in (
            "samples_complete", "samples_broken", "samples_missing", "clock_steps")))

    def receive_filters(self) -> list[dict[str, int | bool]]:
        """python-can ``can_filters`` passing exactly the frames the drives' bus maps and
        sample clocks read (each ID with a full mask, standard and extended kept apart): on
        SocketCAN the kernel drops the rest before they wake the monitor."""
        return [{"can_id": fid, "can_mask": 0x1FFFFFFF if extended else 0x7FF,
                 "extended": extended} for fid, extended in sorted(self._owners_of)]

    @property
    def mapped_frames(self) -> int:
        """Frames received whose ID a drive's bus map or sample clock reads, valid or not: the
        drives' traffic, without the bus's foreign IDs (canfdi.bus.traffic watches it)."""
        stats = self.frame_stats
        return stats["frames_received"] - stats["invalid_by_reason"].get("unknown_id", 0)

    def clock_notices(self) -> list[str]:
        """One line for each step of a drive's clock not said yet (canfdi.bus.timegate): the
        service logs them, once each."""
        out = []
        for drive in self.drives:
            steps = drive.clock.gate.steps
            said = self._steps_said.get(drive.name, 0)
            for _, size in steps[said:]:
                who = f"drive {drive.name}: " if len(self.drives) > 1 else ""
                out.append(f"{who}clock stepped by {size / 1e9:+.3f} s; following it (the "
                           "samples across the step are not counted missing)")
            self._steps_said[drive.name] = len(steps)
        return out

    # -- metadata ---------------------------------------------------------------------------
    def metadata(self, truth: list[dict] | None = None) -> dict[str, str]:
        """Run-level strings for the log: config, design, version, and the truth if known."""
        cfg = self.config
        out = {
            "version": __version__,
            "config_name": cfg.name,
            "config_yaml": cfg.path.read_text() if cfg.path and cfg.path.exists() else "",
            "method": cfg.method,
            "drives_json": json.dumps([d.name for d in self.drives]),
        }
        design = self.method.describe(cfg) if self.method.describe is not None else None
        if design is not None:
            out["design_json"] = json.dumps(design)
        if self.diagnoser is not None:
            out["residuals_json"] = json.dumps(self.diagnoser.residual_names)
            out["thresholds_json"] = json.dumps([float(h) for h in self.diagnoser.thresholds])
        if truth is not None:
            out["truth_json"] = json.dumps(truth)
        return out

    # -- the hot path -----------------------------------------------------------------------
    def on_frame(self, timestamp_ns: int, frame_id: int, data: bytes, *, is_extended: bool = False,
                 is_remote: bool = False, is_error: bool = False, is_fd: bool = False
                 ) -> list[OutFrame]:
        """Process one received frame; returns the frames to send in reply (fault frames)."""
        if self.first_timestamp_ns is None:
            self.first_timestamp_ns = timestamp_ns
        self.last_timestamp_ns = timestamp_ns
        mask = self._owners_of.get(message_key(frame_id, is_extended), 1)
        delivered: list[tuple[Drive, list[Sample]]] = []
        first_status = None
        for drive in self.drives:
            if mask >> drive.index & 1:
                status, samples = drive.clock.push(timestamp_ns, frame_id, data,
                                                   is_extended=is_extended, is_remote=is_remote,
                                                   is_error=is_error, is_fd=is_fd)
                first_status = first_status or status  # a shared frame's: its first drive's
                delivered.append((drive, samples))
        self._frame_counts[STATUS_CODES[first_status]] += 1
        if self.sink is not None:
            self.sink.write_frame(timestamp_ns, frame_id, bytes(data), first_status, is_extended)
        out: list[OutFrame] = []
        for drive, samples in delivered:
            for sample in samples:
                out.extend(self.on_sample(sample, drive))
        return out

    def on_frames(self, block: FrameBlock) -> list[OutFrame]:
        """Process a block of received frames at once (the fast path: vectorised decode and
        assembly, residuals and detection over the whole block; same results as on_frame)."""
        if block.size == 0:
            return []
        if self.first_timestamp_ns is None:
            self.first_timestamp_ns = int(block.t_ns[0])
        self.last_timestamp_ns = int(block.t_ns[-1])
        if len(self.drives) == 1:
            log = self.drives[0].clock.push_batch(block)
            if self.sink is not None:
                self.sink.write_frames(block, log.statuses, STATUS_NAMES)
            return self.on_samples(log.k, log.timestamp_ns, log.u, log.z, log.gap)
        masks = self._masks(block)
        statuses = np.full(block.size, -1, dtype=np.int8)
        logs = []
        for drive in self.drives:
            rows = np.flatnonzero(masks >> drive.index & 1)
            if rows.size:
                log = drive.clock.push_batch(block.select(rows))
                first = statuses[rows] < 0  # a shared frame's status is its first drive's
                statuses[rows[first]] = log.statuses[first]
                logs.append((drive, log))
        self._frame_counts += np.bincount(statuses, minlength=len(STATUS_NAMES))
        if self.sink is not None:
            self.sink.write_frames(block, statuses, STATUS_NAMES)
        out: list[OutFrame] = []
        for drive, log in logs:
            out += self.on_samples(log.k, log.timestamp_ns, log.u, log.z, log.gap, drive)
        return out

    def _masks(self, block: FrameBlock) -> np.ndarray:
        """(N,) int64 bit masks of the drives each frame goes to (the first for a frame of no
        drive)."""
        key = block.id.astype(np.int64) + (((block.flags & FLAG_EXTENDED) != 0)
                                           .astype(np.int64) << 32)
        if not len(self._owner_keys):
            return np.ones(block.size, dtype=np.int64)
        pos = np.clip(np.searchsorted(self._owner_keys, key), 0, len(self._owner_keys) - 1)
        return np.where(self._owner_keys[pos] == key, self._owner_mask[pos], 1)

    def on_samples(self, k: np.ndarray, t_ns: np.ndarray, U: np.ndarray, Z: np.ndarray,
                   gap: np.ndarray, drive: Drive | None = None) -> list[OutFrame]:
        """Diagnose a block of one drive's assembled samples ((N,) k, t_ns, gap; (N, p) U;
        (N, q) Z; default the first drive)."""
        drive = drive or self.drives[0]
        if len(k) == 0:
            return []
        drive.samples += len(k)
        cfg = self.config
        if self.sink is not None:
            self.sink.write_samples(k, t_ns, U, Z, gap, cfg.inputs, cfg.outputs, drive.name)
        dg = drive.diagnoser
        if dg is None:
            return []
        result = dg.update_block(k, t_ns, U, Z, gap)
        self._record_residuals(drive, k, t_ns, result)
        return self._announce(result.events, drive)

    def on_sample(self, sample: Sample, drive: Drive | None = None) -> list[OutFrame]:
        """Diagnose one assembled sample of a drive (default the first)."""
        drive = drive or self.drives[0]
        drive.samples += 1
        dg = drive.diagnoser
        events = dg.update(sample) if dg is not None else []
        if self.sink is not None:
            self.sink.write_sample(sample, self.config.inputs, self.config.outputs, drive.name)
            if dg is not None and self.record_residuals and dg.last_residuals is not None:
                self.sink.write_residuals(sample.timestamp_ns, sample.k, dg.residual_names,
                                          dg.last_residuals, dg.last_normalized,
                                          dg.statistics, drive.name)
        return self._announce(events, drive)

    @property
    def teaching(self) -> bool:
        """Whether a drive is still being taught."""
        return any(d.state == "teaching" for d in self.drives)

    def _record_residuals(self, drive: Drive, k: np.ndarray, t_ns: np.ndarray,
                          result: BlockResult) -> None:
        """The residual rows of samples k (N,) to the sink, those with any value."""
        if self.sink is None or not self.record_residuals:
            return
        R, Rn, stat = result.residuals, result.normalized, result.statistic
        have = ~np.isnan(R).all(axis=1)
        if have.any():
            self.sink.write_residual_rows(k[have], t_ns[have], drive.diagnoser.residual_names,
                                          R[have], Rn[have], stat[have], drive.name)

    def _announce(self, events: list[FaultEvent], drive: Drive) -> list[OutFrame]:
        out: list[OutFrame] = []
        for event in events:
            event = replace(event, drive=drive.name)
            self.events.append(event)
            if self.sink is not None:
                self.sink.write_event(event)
                self.sink.write_log(event.timestamp_ns, event_level(event),
                                    event_line(event, self.dt, len(self.drives) > 1).strip(),
                                    f"canfdi.{drive.name}")
            out.extend(self.fault_frames(event, drive))
        return out

    # -- frames of ours ---------------------------------------------------------------------
    def _encode(self, name: str, values: dict[str, float]) -> OutFrame | None:
        found = self.frames.encode(name, values)
        if found is None:
            return None
        (frame_id, extended), data = found
        return OutFrame(frame_id, data, extended)

    def fault_frames(self, event: FaultEvent, drive: Drive | None = None) -> list[OutFrame]:
        """FDI_FAULT (and FDI_ESTIMATE per estimate) frames announcing an event; a refinement
        sends only the channel's updated FDI_ESTIMATEs (none at all when listen-only)."""
        if event.kind not in _STATE and event.kind != "refined":
            return []
        frames = []
        if event.kind in _STATE:  # a refinement updates the estimate of a fault already known
            frames.append(self._encode("FDI_FAULT", self.fault_values(event, drive)))
        for key, value in event.estimates.items():
            if key not in _PARAM:
                continue
            frames.append(self._encode("FDI_ESTIMATE",
                                       self.estimate_values(event, key, value, drive)))
            var = event.variances.get(key)
            if var is not None:
                std = float(np.sqrt(max(var, 0.0)))
                frames.append(self._encode("FDI_ESTIMATE",
                                           self.estimate_values(event, key, std, drive, True)))
        return [f for f in frames if f is not None]

    def fault_values(self, event: FaultEvent, drive: Drive | None = None) -> dict[str, int]:
        """FDI_FAULT's signal values announcing ``event`` (detected, named or accepted): the
        channel's kind and index (0 for a detection, which names none), the state, the
        drive's index and the sample modulo 2^32 (what `canfdi codegen`'s C loop sends too)."""
        return _bounded("FDI_FAULT", {
            "Kind": _KIND.get(event.target or "", 0), "State": _STATE[event.kind],
            "Drive": (drive or self.drives[0]).index, "Index": event.index or 0,
            "Sample": event.sample})

    def estimate_values(self, event: FaultEvent, key: str, value: float,
                        drive: Drive | None = None, std: bool = False) -> dict[str, float]:
        """FDI_ESTIMATE's signal values for the estimate ``key`` of ``event`` ("eta",
        "lambda" or "bias"): ``value`` itself, or with ``std`` its standard deviation."""
        return {"Kind": _KIND[event.target], "Param": _PARAM[key] + (STD_PARAM if std else 0),
                "Drive": (drive or self.drives[0]).index, "Index": event.index,
                "Value": value}

    def status_values(self, drive: Drive, state: str | None = None) -> dict[str, int]:
        """FDI_STATUS's signal values of one drive: its state (``state`` overrides it), the
        channels compensated (at most 15), the samples modulo 2^21 and the invalid frames
        modulo 2^16."""
        return _bounded("FDI_STATUS", {
            "State": _STATUS[state or drive.state], "Drive": drive.index,
            "ActiveFaults": _active_faults(drive), "Samples": drive.samples,
            "InvalidFrames": drive.clock.stats["frames_invalid"]})

    def record_status(self, timestamp_ns: int, state: str | None = None) -> None:
        """Record the status the heartbeat reports on the sink's ``/canfdi/status``: the
        state of each drive (``name=state``, comma-separated), samples, the assembler's
        counters and the active faults."""
        if self.sink is None:
            return
        states = ",".join(f"{d.name}={state or d.state}" for d in self.drives)
        active = sum(_active_faults(d) for d in self.drives)
        self.sink.write_status(timestamp_ns, states, self.samples, self.frame_stats, active)

    def status_frames(self, state: str | None = None) -> list[OutFrame]:
        """The periodic FDI_STATUS heartbeat, one per drive (none when listen-only)."""
        out = []
        for drive in self.drives:
            frame = self._encode("FDI_STATUS", self.status_values(drive, state))
            if frame is not None:
                out.append(frame)
        return out

    # -- results ----------------------------------------------------------------------------
    def finish(self) -> list[OutFrame]:
        """End of stream: a pending incomplete sample is diagnosed as broken; returns the
        frames that caused (usually none)."""
        out: list[OutFrame] = []
        for drive in self.drives:
            for sample in drive.clock.flush():
                out.extend(self.on_sample(sample, drive))
        return out

    def summary(self, truth: list[dict] | None = None) -> dict[str, Any]:
        """The JSON contract of `replay --json` and `demo --json`."""
        out = summary_json(self.events, self.frame_stats, self.dt, truth, self.samples)
        if len(self.drives) > 1:
            out["drives"] = {d.name: {"samples": d.samples, "frames": d.clock.stats}
                             for d in self.drives}
        return out


def _active_faults(drive: Drive) -> int:
    """The channels a drive's diagnoser compensates now (0 without a diagnoser)."""
    dg = drive.diagnoser
    return len({(c.target, c.index) for c in dg.compensation}) if dg is not None else 0


def summary_json(events: list[FaultEvent], frame_stats: dict, dt: float,
                 truth: list[dict] | None, samples: int) -> dict[str, Any]:
    """{"faults": [...] (each with its named_sample: when its component was named, at its
    acceptance at the latest), "named": [...] (faults named before they were identified),
    "unexplained": [...], "refined": [...] (updates of a fault's estimate),
    "mismatches": [...] (the noise watchdog's: noisier than configured), "quiet": [...]
    (quieter than configured), "detections": N, "frames": {...},
    "samples": N, "truth": [...] when known}."""
    detections = {(e.drive, e.sample): e for e in events if e.kind == "detected"}
    named_at = {(e.drive, e.detected_sample): e.sample for e in events if e.kind == "named"}
    faults = []
    for e in events:
        if e.kind != "accepted":
            continue
        detected = detections.get((e.drive, e.detected_sample))
        faults.append({
            "kind": e.target, "index": e.index, "name": e.name, "drive": e.drive,
            "onset_sample": e.onset_sample, "detected_sample": e.detected_sample,
            "named_sample": named_at.get((e.drive, e.detected_sample), e.accepted_sample),
            "accepted_sample": e.accepted_sample,
            "detected_time": (detected.timestamp_ns / 1e9 if detected is not None else None),
            "estimate": dict(e.estimates), "variance": dict(e.variances),
            "candidates": list(e.candidates),
        })
    named = [{"kind": e.target, "index": e.index, "name": e.name, "drive": e.drive,
              "sample": e.sample, "onset_sample": e.onset_sample,
              "detected_sample": e.detected_sample, "estimate": dict(e.estimates),
              "variance": dict(e.variances), "undecided": list(e.undecided),
              "candidates": list(e.candidates)} for e in events if e.kind == "named"]
    unexplained = [e.as_dict() for e in events if e.kind == "unexplained"]
    refined = [{"kind": e.target, "index": e.index, "name": e.name, "drive": e.drive,
                "onset_sample": e.onset_sample, "detected_sample": e.detected_sample,
                "accepted_sample": e.accepted_sample, "estimate": dict(e.estimates)}
               for e in events if e.kind == "refined"]
    mismatches = [e.as_dict() for e in events if e.kind == "mismatch"]
    quiet = [e.as_dict() for e in events if e.kind == "quiet"]
    out: dict[str, Any] = {
        "faults": faults,
        "named": named,
        "unexplained": unexplained,
        "refined": refined,
        "mismatches": mismatches,
        "quiet": quiet,
        "detections": len(detections),
        "samples": samples,
        "frames": {
            "received": frame_stats["frames_received"],
            "valid": frame_stats["frames_valid"],
            "invalid": frame_stats["frames_invalid"],
            "invalid_by_reason": dict(frame_stats["invalid_by_reason"]),
            "samples_complete": frame_stats["samples_complete"],
            "samples_broken": frame_stats["samples_broken"],
            "samples_missing": frame_stats["samples_missing"],
            "clock_steps": frame_stats.get("clock_steps", 0),
        },
    }
    if samples == 0:
        out["no_samples"] = no_samples_reason(out["frames"])
    if truth is not None:
        out["truth"] = truth
    return out


def no_samples_reason(frames: dict) -> str:
    """Why a run assembled no sample, from its frame counters (the keys of summary "frames")."""
    if frames["received"] == 0:
        return "0 samples: the log holds no CAN frame"
    rejected = ", ".join(f"{n} {reason}" for reason, n in frames["invalid_by_reason"].items() if n)
    if frames["valid"] == 0:
        return (f"0 samples: no frame matched the config's bus map ({frames['received']} frames: "
                f"{rejected}); check bus.map, the node ids of drives: and bus.e2e")
    return (f"0 samples: {frames['valid']} frames matched the map but no control period was "
            f"complete ({rejected or 'none rejected'}); check the sample clock (bus.clock)")
