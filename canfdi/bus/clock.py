"""Sample clocks: how one sample per control period is formed from a drive's frames.

Chosen by name in the config (``bus.clock.kind``, docs/bus.md); `make_clock` is the only place
that branches on the name. Every clock takes frames streaming (``push``: one frame) and by the
block (``push_batch``: a `FrameBlock`), with the same results, and returns samples as
canfdi.bus.assembler's `AssembledLog`:

* ``counter``: canfdi.bus.assembler's `SampleAssembler`: sample k is complete when every mapped
  message has arrived with alive counter k (unwrapped by time); the messages' E2E profiles give
  the counters.
* ``trigger``: every valid frame of one message (CANopen SYNC, or the drive's own feedback
  frame) closes a sample holding the newest value of each mapped signal received up to and
  including it, if not older than ``max_age``; lost triggers are counted from the time between
  them. The first trigger only starts the clock (what came before it is no whole period): the
  second closes sample 0, so that on a CANopen bus sample k holds period k (SYNC k+1 closes
  the PDOs sent after SYNC k).
* ``grid``: samples at fixed instants ``t0 + phase + k period`` (t0: the first mapped frame's
  arrival), each holding the newest value of each mapped signal received up to the instant, if
  not older than ``max_age``. A sample is delivered once a valid frame of the drive's DBC later
  than its instant has arrived (only the drive's own frames move its clock: a foreign frame's
  time is not checked).

Every clock first passes the drive's valid frames through a `canfdi.bus.timegate.TimeGate`: a
frame whose time leaves the drive's by more than the bound is a ``time_jump``, dropped; a step
of the clock is followed, not materialised as missing samples.

A value too old, or never received, is NaN: the diagnoser treats it as a lost frame's. A frame
whose message has an alive counter and repeats its predecessor's count is a ``duplicate``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from canfdi.bus.assembler import AssembledLog, SampleAssembler, dest_table
from canfdi.bus.dbc import BusMap
from canfdi.bus.frames import (
    FLAG_ERROR,
    FLAG_EXTENDED,
    FLAG_FD,
    FLAG_REMOTE,
    STATUS_CODES,
    STATUS_NAMES,
    FrameBlock,
    frame_counters,
)
from canfdi.bus.timegate import MIN_BOUND_PERIODS, TimeGate
from canfdi.core.records import Sample
from canfdi.core.settings import ClockConfig, ConfigError, brief

__all__ = ["CLOCKS", "LatestValueClock", "latest_values", "make_clock"]

CLOCKS = ("counter", "trigger", "grid")
"""The sample clocks a config can name (``bus.clock.kind``)."""

_OK = STATUS_CODES["ok"]
_DUPLICATE = STATUS_CODES["duplicate"]
_UNUSED = STATUS_CODES["unused"]
_TIME_JUMP = STATUS_CODES["time_jump"]
_NEVER = np.iinfo(np.int64).min


class LatestValueClock:
    """The ``trigger`` and ``grid`` clocks: samples of the newest value of each signal.

    Parameters
    ----------
    bus_map : the drive's compiled map (its ``trigger_slot`` for a trigger clock).
    dt : the control period, seconds (> 0): counts lost triggers, the grid's default period.
    kind : "trigger" or "grid".
    period, phase, max_age : seconds (None: dt, period / 2, 1.5 dt).

    Examples
    --------
    A grid clock on the shipped dc_motor config's drive (DRIVE_CMD 0x104: V, DRIVE_CURRENTS
    0x105: i_f, i_a, i_f_plus_i_a, DRIVE_SPEED 0x106: omega_r): the first frame at t = 0 puts
    sample k at (k + 1/2) 10 ms, delivered by the first frame after it:

    >>> from canfdi.bus.dbc import BusMap
    >>> from canfdi.bus.e2e import protect
    >>> from canfdi.core.settings import BusConfig, MonitorConfig
    >>> config = MonitorConfig.of_bus("dc_motor", ["V"], ["i_f", "i_a", "i_f_plus_i_a", "omega_r"],
    ...                               BusConfig(dbc="motor_drive"))
    >>> bus_map = BusMap.from_config(config)
    >>> cmd = protect(0x104, bytes(2) + (1200).to_bytes(2, "little") + bytes(4), 0)
    >>> currents = protect(0x105, bytes(2) + bytes.fromhex("f401b80bac0d"), 0)
    >>> speed = protect(0x106, bytes(2) + (10000).to_bytes(2, "little"), 0)
    >>> clock = LatestValueClock(bus_map, 0.01, "grid")
    >>> [clock.push(t, frame_id, data) for t, frame_id, data in
    ...  [(0, 0x104, cmd), (130_000, 0x105, currents), (260_000, 0x106, speed)]]
    [('ok', []), ('ok', []), ('ok', [])]
    >>> status, [sample] = clock.push(10_000_000, 0x104, protect(0x104, cmd, 1))
    >>> sample.k, sample.timestamp_ns, sample.u.tolist(), sample.z.tolist()
    (0, 5000000, [12.0], [0.5, 3.0, 3.5, 100.0])
    """

    def __init__(self, bus_map: BusMap, dt: float, kind: str, *, period: float | None = None,
                 phase: float | None = None, max_age: float | None = None) -> None:
        if not (isinstance(dt, int | float) and math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt: the control period must be a number of seconds > 0, got "
                             f"{dt!r}")
        if kind == "trigger" and bus_map.trigger_slot is None:
            raise ValueError("a trigger clock needs the bus map's trigger message")
        self.bus_map = bus_map
        self.kind = kind
        self.dt = float(dt)
        self._dt_ns = float(dt) * 1e9
        self._period_ns = (period or dt) * 1e9
        self._phase_ns = (phase if phase is not None else (period or dt) / 2.0) * 1e9
        self._max_age_ns = (max_age if max_age is not None else 1.5 * dt) * 1e9
        width = bus_map.p + bus_map.q
        self._value = np.full(width, np.nan)
        self._time = np.full(width, np.iinfo(np.int64).min // 4, dtype=np.int64)
        self._last_counter = np.full(len(bus_map.layouts), -1, dtype=np.int64)
        self._k = -1  # latest sample delivered
        self._t_last: int | None = None  # its instant (trigger time or grid instant), ns;
        # trigger: the first trigger's time once seen (it starts the clock, closes nothing)
        self._t0: int | None = None  # grid: the first mapped frame's time
        self._counts = [0] * len(STATUS_NAMES)
        self._complete = self._broken = self._missing = 0
        self.gate = TimeGate(round(MIN_BOUND_PERIODS * max(self._dt_ns, self._period_ns)))
        self._dest = dest_table(bus_map._dests)
        # The block form of the samples' values: `latest_values`, unless canfdi.core.kernel
        # installed its C core's (the same numbers).
        self.latest_values = self.latest_values_reference = latest_values

    @property
    def stats(self) -> dict:
        """Counters since construction, as `SampleAssembler.stats`."""
        return frame_counters(self._counts, self._complete, self._broken, self._missing,
                              len(self.gate.steps))

    # -- streaming ----------------------------------------------------------------------------
    def push(self, timestamp_ns: int, frame_id: int, data: bytes | bytearray, *,
             is_extended: bool = False, is_remote: bool = False, is_error: bool = False,
             is_fd: bool = False) -> tuple[str, list[Sample]]:
        """Take one frame: (its status, the samples it delivered). The scalar form of
        `push_batch` (a live bus hands frames one by one; a block of one costs ~20x more),
        tested equal to it on every cut of a stream."""
        flags = (is_extended * FLAG_EXTENDED | is_remote * FLAG_REMOTE | is_error * FLAG_ERROR
                 | is_fd * FLAG_FD)
        status, slot, values, counter = self.bus_map.decode_frame(frame_id, data, flags)
        code = STATUS_CODES[status]
        t = int(timestamp_ns)
        if code in (_OK, _UNUSED):
            checked = self.gate.step(t)
            if checked is None:
                code = _TIME_JUMP
            else:
                t = checked
        if code == _OK and counter >= 0:
            if counter == self._last_counter[slot]:
                code = _DUPLICATE
            self._last_counter[slot] = counter
        self._counts[code] += 1
        if self.kind == "trigger":
            if code == _OK:
                self._store(slot, values, t)  # the trigger frame's own values count
            if code != _OK or slot != self.bus_map.trigger_slot:
                return STATUS_NAMES[code], []
            if self._t_last is None:  # the first trigger starts the clock
                self._t_last = t
                return STATUS_NAMES[code], []
            instants = np.array([t], dtype=np.int64)
        else:
            if code == _OK and self._t0 is None:
                self._t0 = t
            instants, _ = self._grid_instants(np.array(
                [t if code in (_OK, _UNUSED) else _NEVER], dtype=np.int64))
        samples = []
        if len(instants):
            ks, gaps = self._indices(instants)
            fresh = instants[:, None] - self._time[None, :] <= self._max_age_ns
            rows = np.where(fresh, self._value[None, :], np.nan)
            missing = np.isnan(rows).any(axis=1)
            self._complete += int((~missing).sum())
            self._broken += int(missing.sum())
            p = self.bus_map.p
            samples = [Sample(k=int(k), timestamp_ns=int(at), u=row[:p], z=row[p:], gap=int(g))
                       for k, at, g, row in zip(ks.tolist(), instants.tolist(), gaps.tolist(),
                                                rows, strict=True)]
        if self.kind == "grid" and code == _OK:
            self._store(slot, values, t)  # after: every final instant is before this frame
        return STATUS_NAMES[code], samples

    def _store(self, slot: int, values: tuple[float, ...], t: int) -> None:
        """Keep a valid frame's values as the newest of their signals."""
        for dest, value in zip(self.bus_map._dests[slot], values, strict=True):
            self._value[dest] = value
            self._time[dest] = t

    def flush(self) -> list[Sample]:
        """End of stream: nothing pending (a trigger delivers at once; a grid instant later
        than the last frame has nothing newer to show)."""
        return []

    # -- blocks -------------------------------------------------------------------------------
    def push_batch(self, block: FrameBlock) -> AssembledLog:
        """`push` for a block of frames, in order (vectorised)."""
        status, slot, values, counters = self.bus_map.decode_frames(block)
        drive = np.flatnonzero((status == _OK) | (status == _UNUSED))
        t, dropped = self.gate.apply(block.t_ns, drive)
        status[drive[dropped]] = _TIME_JUMP
        self._mark_duplicates(status, slot, counters)
        ok = np.flatnonzero(status == _OK)
        if self.kind == "trigger":
            at = ok[slot[ok] == self.bus_map.trigger_slot]
            if self._t_last is None and at.size:
                # The first trigger starts the clock: what came before it is no whole period.
                self._t_last = int(t[at[0]])
                at = at[1:]
            instants, upto = self._trigger_instants(t, at)
        else:
            start = 0
            if self._t0 is None and ok.size:
                # The first valid frame starts the grid: frames before it close no instant
                # (a jittered stray stamped later than it would, the scalar path shows).
                start = int(ok[0])
                self._t0 = int(t[start])
            # Only the drive's own valid frames move its clock.
            own = (status[start:] == _OK) | (status[start:] == _UNUSED)
            instants, upto = self._grid_instants(np.where(own, t[start:], _NEVER))
            upto = upto + start
        ks, gaps = self._indices(instants)
        flat = self._values_at(ok, slot, values, t, instants, upto)
        for code, count in enumerate(np.bincount(status, minlength=len(STATUS_NAMES))):
            self._counts[code] += int(count)
        missing = np.isnan(flat).any(axis=1)
        self._complete += int((~missing).sum())
        self._broken += int(missing.sum())
        p = self.bus_map.p
        return AssembledLog(k=ks, timestamp_ns=instants, u=flat[:, :p], z=flat[:, p:], gap=gaps,
                            statuses=status, stats=self.stats)

    def _mark_duplicates(self, status: NDArray[np.int8], slot: NDArray[np.int16],
                         counters: NDArray[np.int64]) -> None:
        """A counter-bearing frame repeating its message's previous count is a duplicate."""
        for s in range(len(self.bus_map.layouts)):
            rows = np.flatnonzero((status == _OK) & (slot == s) & (counters >= 0))
            if not rows.size:
                continue
            c = counters[rows]
            previous = np.concatenate([[self._last_counter[s]], c[:-1]])
            repeat = c == previous
            # A repeat of a repeat compares with the kept frame's count, which is the same.
            status[rows[repeat]] = _DUPLICATE
            self._last_counter[s] = c[-1]

    def _trigger_instants(self, t: NDArray[np.int64], at: NDArray[np.intp]
                          ) -> tuple[NDArray[np.int64], NDArray[np.intp]]:
        """Sample instants (the trigger frames' times) and, per sample, the last row counted."""
        return t[at].astype(np.int64), at

    def _grid_instants(self, t: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.intp]]:
        """The grid instants this block makes final (earlier than its latest frame), and per
        instant the last row received up to it."""
        if self._t0 is None or not len(t) or int(np.max(t)) == _NEVER:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.intp)
        latest = int(np.max(t))
        first = self._k + 1
        last = math.ceil((latest - self._t0 - self._phase_ns) / self._period_ns) - 1
        if last < first:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.intp)
        k = np.arange(first, last + 1)
        instants = (self._t0 + self._phase_ns + k * self._period_ns).astype(np.int64)
        # Frames come in arrival order; a running maximum makes the times searchable.
        upto = np.searchsorted(np.maximum.accumulate(t), instants, side="right") - 1
        return instants, upto.astype(np.intp)

    def _indices(self, instants: NDArray[np.int64]) -> tuple[NDArray[np.int64],
                                                             NDArray[np.int64]]:
        """Sample indices and gaps of the new samples; the state moves to the last."""
        n = len(instants)
        if n == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        if self.kind == "grid":
            ks = np.arange(self._k + 1, self._k + 1 + n, dtype=np.int64)
            gaps = np.zeros(n, dtype=np.int64)
        else:
            previous = np.concatenate([[self._t_last], instants[:-1]])
            steps = np.maximum(np.rint((instants - previous) / self._dt_ns), 1).astype(np.int64)
            ks = self._k + np.cumsum(steps)
            gaps = steps - 1
            self._missing += int(gaps.sum())
        self._k = int(ks[-1])
        self._t_last = int(instants[-1])
        return ks, gaps

    def _values_at(self, ok: NDArray[np.intp], slot: NDArray[np.int16],
                   values: NDArray[np.float64], t: NDArray[np.int64],
                   instants: NDArray[np.int64], upto: NDArray[np.intp]) -> NDArray[np.float64]:
        """(S, p + q): per sample the newest value of each signal received by row ``upto``,
        NaN when older than max_age at the instant; the state keeps the newest of the block
        (`latest_values`, on the kernel installed)."""
        return self.latest_values(ok, slot, values, t, instants, upto, self._dest,
                                  self._max_age_ns, self._value, self._time)


def latest_values(ok: NDArray[np.intp], slot: NDArray[np.int16], values: NDArray[np.float64],
                  t: NDArray[np.int64], instants: NDArray[np.int64], upto: NDArray[np.intp],
                  dest: NDArray[np.int64], max_age_ns: float, value: NDArray[np.float64],
                  time: NDArray[np.int64]) -> NDArray[np.float64]:
    """The latest-value clocks' samples, in numpy (the reference of the kernels' form).

    Parameters
    ----------
    ok : (V,) ascending rows of the block's valid drive frames; slot, t : (N,) every row's
        slot and (gate-checked) time; values : (N, >= cols) the decoded fields.
    instants : (S,) the samples' instants; upto : (S,) non-decreasing, each sample's last row
        counted (-1: none of the block's).
    dest : (slots, cols) each slot's fields' positions in a row (`dest_table`), -1 beyond.
    max_age_ns : the oldest a value may be at an instant.
    value, time : (W,) each position's newest value and its time before the block; updated to
        the newest of the block.

    Returns
    -------
    (S, W) per sample the newest value of each position received by its last row, NaN when
    older than max_age (or never received).
    """
    width = len(value)
    out = np.full((len(instants), width), np.nan)
    for s in range(dest.shape[0]):
        rows = ok[slot[ok] == s]
        for col in range(dest.shape[1]):
            to = int(dest[s, col])
            if to < 0:
                continue
            # Updates of this signal: the kept one (before the block) and the block's.
            times = np.concatenate([[time[to]], t[rows]])
            vals = np.concatenate([[value[to]], values[rows, col]])
            if len(instants):
                newest = np.searchsorted(rows, upto, side="right")  # 0: the kept one
                fresh = instants - times[newest] <= max_age_ns
                out[:, to] = np.where(fresh, vals[newest], np.nan)
            time[to], value[to] = times[-1], vals[-1]
    return out


def make_clock(bus_map: BusMap, dt: float, clock: ClockConfig
               ) -> SampleAssembler | LatestValueClock:
    """The sample clock the config names for one drive."""
    if clock.kind == "counter":
        return SampleAssembler(bus_map, dt)
    if clock.kind in ("trigger", "grid"):
        return LatestValueClock(bus_map, dt, clock.kind, period=clock.period, phase=clock.phase,
                                max_age=clock.max_age)
    raise ConfigError("bus.clock.kind", f"unknown clock {brief(clock.kind)} (known: "
                                        f"{', '.join(CLOCKS)})")
