"""The monitor without I/O: frames in; samples, diagnoses, fault frames and log records out.

`canfdi run`, `demo`, `capture` and `replay` all drive one Monitor: the live verbs from the
asyncio service, replay from a log. Nothing here reads a clock, a bus or a file: timestamps come
with the frames, frames to send are returned, records go to an optional sink (the MCAP recorder).

    frame -> SampleAssembler (E2E checks, counters, gaps) -> Sample
          -> Diagnoser.update -> FaultEvents -> FDI_FAULT / FDI_ESTIMATE frames
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from canfdi import __version__, methods
from canfdi.bus.assembler import SampleAssembler
from canfdi.bus.dbc import BusMap
from canfdi.bus.e2e import protect
from canfdi.bus.frames import STATUS_NAMES, FrameBlock
from canfdi.core.protocol import DIAGNOSE, Diagnoser
from canfdi.core.records import FaultEvent, Sample
from canfdi.core.settings import MonitorConfig

__all__ = ["Monitor", "OutFrame", "RecordSink", "summary_json"]


_KIND = {"actuator": 1, "sensor": 2}
_STATE = {"detected": 1, "accepted": 3}
_PARAM = {"eta": 0, "lambda": 1, "bias": 2}
_STATUS = {"starting": 0, "monitoring": 1, "diagnosing": 2, "degraded": 3, "bus_error": 4}


class RecordSink(Protocol):
    """Where the monitor's records go (canfdi.io.writer.McapRecorder fits)."""

    def write_frame(self, timestamp_ns: int, frame_id: int, data: bytes, status: str,
                    extended: bool = False) -> None: ...
    def write_sample(self, sample: Sample, input_names: list[str],
                     output_names: list[str]) -> None: ...
    def write_residuals(self, timestamp_ns: int, k: int, names: list[str], r: np.ndarray,
                        normalized: np.ndarray, statistic: np.ndarray) -> None: ...
    def write_event(self, event: FaultEvent) -> None: ...
    def write_frames(self, block: FrameBlock, statuses: np.ndarray,
                     status_names: tuple[str, ...]) -> None: ...
    def write_samples(self, k: np.ndarray, t_ns: np.ndarray, U: np.ndarray, Z: np.ndarray,
                      gap: np.ndarray, input_names: list[str],
                      output_names: list[str]) -> None: ...
    def write_residual_rows(self, k: np.ndarray, t_ns: np.ndarray, names: list[str],
                            R: np.ndarray, Rn: np.ndarray, stat: np.ndarray) -> None: ...


@dataclass(frozen=True)
class OutFrame:
    """A frame the monitor wants on the bus."""

    frame_id: int
    data: bytes


class Monitor:
    """Frames to diagnoses for one config.

    Parameters
    ----------
    config : the monitor config (bus.dbc must name the drive's DBC).
    sink : optional record sink (MCAP recorder).
    record_residuals : write every sample's residuals to the sink (the bulk of a log).
    diagnose : False for capture: decode and record, no diagnosis (and no calibration).
    """

    def __init__(self, config: MonitorConfig, sink: RecordSink | None = None,
                 record_residuals: bool = True, diagnose: bool = True) -> None:
        self.config = config
        self.bus_map = BusMap.from_config(config)
        self.method = methods.get(config.method)
        self.diagnoser: Diagnoser | None = self.method.build(config) if diagnose else None
        self.dt = config.model.dt or 1.0
        self.assembler = SampleAssembler(self.bus_map, self.dt)
        self.sink = sink
        self.record_residuals = record_residuals
        self.events: list[FaultEvent] = []
        self.samples = 0
        self.first_timestamp_ns: int | None = None
        self._counters: dict[int, int] = {}
        self._fdi = {lay.name: lay for lay in self.bus_map.monitor_layouts}

    # -- metadata ---------------------------------------------------------------------------
    def metadata(self, truth: list[dict] | None = None) -> dict[str, str]:
        """Run-level strings for the log: config, design, version, and the truth if known."""
        cfg = self.config
        out = {
            "version": __version__,
            "config_name": cfg.name,
            "config_yaml": cfg.path.read_text() if cfg.path and cfg.path.exists() else "",
            "method": cfg.method,
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
        status, samples = self.assembler.push(timestamp_ns, frame_id, data,
                                              is_extended=is_extended, is_remote=is_remote,
                                              is_error=is_error, is_fd=is_fd)
        if self.sink is not None:
            self.sink.write_frame(timestamp_ns, frame_id, bytes(data), status, is_extended)
        out: list[OutFrame] = []
        for sample in samples:
            out.extend(self.on_sample(sample))
        return out

    def on_frames(self, block: FrameBlock) -> list[OutFrame]:
        """Process a block of received frames at once (the fast path: vectorised decode and
        assembly, residuals and detection over the whole block; same results as on_frame)."""
        if block.size == 0:
            return []
        if self.first_timestamp_ns is None:
            self.first_timestamp_ns = int(block.t_ns[0])
        log = self.assembler.push_batch(block)
        if self.sink is not None:
            self.sink.write_frames(block, log.statuses, STATUS_NAMES)
        return self.on_samples(log.k, log.timestamp_ns, log.u, log.z, log.gap)

    def on_samples(self, k: np.ndarray, t_ns: np.ndarray, U: np.ndarray, Z: np.ndarray,
                   gap: np.ndarray) -> list[OutFrame]:
        """Diagnose a block of assembled samples ((N,) k, t_ns, gap; (N, p) U; (N, q) Z)."""
        if len(k) == 0:
            return []
        self.samples += len(k)
        dg = self.diagnoser
        if self.sink is not None:
            self.sink.write_samples(k, t_ns, U, Z, gap, self.config.inputs, self.config.outputs)
        if dg is None:
            return []
        result = dg.update_block(k, t_ns, U, Z, gap)
        if self.sink is not None and self.record_residuals:
            have = ~np.isnan(result.residuals).all(axis=1)
            if have.any():
                self.sink.write_residual_rows(k[have], t_ns[have], dg.residual_names,
                                              result.residuals[have], result.normalized[have],
                                              result.statistic[have])
        out: list[OutFrame] = []
        for event in result.events:
            self.events.append(event)
            if self.sink is not None:
                self.sink.write_event(event)
            out.extend(self.fault_frames(event))
        return out

    def on_sample(self, sample: Sample) -> list[OutFrame]:
        """Diagnose one assembled sample (replay of decoded samples enters here)."""
        self.samples += 1
        dg = self.diagnoser
        events = dg.update(sample) if dg is not None else []
        if self.sink is not None:
            self.sink.write_sample(sample, self.config.inputs, self.config.outputs)
            if dg is not None and self.record_residuals and dg.last_residuals is not None:
                self.sink.write_residuals(sample.timestamp_ns, sample.k, dg.residual_names,
                                          dg.last_residuals, dg.last_normalized, dg.statistics)
        out: list[OutFrame] = []
        for event in events:
            self.events.append(event)
            if self.sink is not None:
                self.sink.write_event(event)
            out.extend(self.fault_frames(event))
        return out

    # -- frames of ours ---------------------------------------------------------------------
    def _encode(self, name: str, values: dict[str, float]) -> OutFrame | None:
        layout = self._fdi.get(name)
        if layout is None:
            return None
        payload, _ = layout.encode({k: np.array([v]) for k, v in values.items()}, 1)
        counter = self._counters.get(layout.frame_id, 0)
        self._counters[layout.frame_id] = (counter + 1) & 0xFF
        return OutFrame(layout.frame_id, protect(layout.frame_id, payload[0].tobytes(), counter))

    def fault_frames(self, event: FaultEvent) -> list[OutFrame]:
        """FDI_FAULT (and FDI_ESTIMATE per estimate) frames announcing an event."""
        if event.kind not in _STATE:
            return []
        frames = [self._encode("FDI_FAULT", {
            "Kind": _KIND.get(event.target or "", 0), "State": _STATE[event.kind],
            "Index": event.index or 0, "Sample": event.sample & 0xFFFFFFFF,
        })]
        for key, value in event.estimates.items():
            param = _PARAM.get(key)
            if param is None:
                continue
            frames.append(self._encode("FDI_ESTIMATE", {
                "Kind": _KIND[event.target], "Param": param, "Index": event.index,
                "Value": value}))
            var = event.variances.get(key)
            if var is not None:
                frames.append(self._encode("FDI_ESTIMATE", {
                    "Kind": _KIND[event.target], "Param": param + 3, "Index": event.index,
                    "Value": float(np.sqrt(max(var, 0.0)))}))
        return [f for f in frames if f is not None]

    def status_frame(self, state: str | None = None) -> OutFrame | None:
        """The periodic FDI_STATUS heartbeat."""
        dg = self.diagnoser
        if state is None:
            state = "diagnosing" if dg is not None and dg.mode == DIAGNOSE else "monitoring"
        stats = self.assembler.stats
        return self._encode("FDI_STATUS", {
            "State": _STATUS[state],
            "ActiveFaults": min(len(dg.compensation), 15) if dg is not None else 0,
            "Samples": self.samples & 0xFFFFFF,
            "InvalidFrames": stats["frames_invalid"] & 0xFFFF,
        })

    # -- results ----------------------------------------------------------------------------
    def finish(self) -> list[OutFrame]:
        """End of stream: a pending incomplete sample is diagnosed as broken; returns the
        frames that caused (usually none)."""
        out: list[OutFrame] = []
        for sample in self.assembler.flush():
            out.extend(self.on_sample(sample))
        return out

    def summary(self, truth: list[dict] | None = None) -> dict[str, Any]:
        """The JSON contract of `replay --json` and `demo --json`."""
        return summary_json(self.events, self.assembler.stats, self.dt, truth, self.samples)


def summary_json(events: list[FaultEvent], frame_stats: dict, dt: float,
                 truth: list[dict] | None, samples: int) -> dict[str, Any]:
    """{"faults": [...], "frames": {...}, "samples": N, "truth": [...] when known}."""
    detections = {e.sample: e for e in events if e.kind == "detected"}
    faults = []
    for e in events:
        if e.kind != "accepted":
            continue
        detected = detections.get(e.detected_sample)
        faults.append({
            "kind": e.target, "index": e.index, "name": e.name,
            "onset_sample": e.onset_sample, "detected_sample": e.detected_sample,
            "accepted_sample": e.accepted_sample,
            "detected_time": (detected.timestamp_ns / 1e9 if detected is not None else None),
            "estimate": dict(e.estimates), "variance": dict(e.variances),
            "candidates": list(e.candidates),
        })
    unexplained = [e.as_dict() for e in events if e.kind == "unexplained"]
    out: dict[str, Any] = {
        "faults": faults,
        "unexplained": unexplained,
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
        },
    }
    if truth is not None:
        out["truth"] = truth
    return out
