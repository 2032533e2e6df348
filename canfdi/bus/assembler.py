"""From CAN frames to samples: the sample assembler, streaming and batch.

The bus contract (``dbc/README.md``, DESIGN.md "The bus contract"): in control period k the
drive sends each of its DBC messages once, every one carrying the E2E header (CRC-8 in byte 0,
alive counter ``k mod 256`` in byte 1). A sample k is complete when every drive message that
carries a model signal has arrived for counter k with the right DLC and CRC. A sample some of
whose messages were lost is *broken*: it is delivered when a later counter closes it (or at
`SampleAssembler.flush`), with NaN for the signals of its missing messages, so the diagnoser
keeps every residual that does not read them. Each sample carries ``gap`` = samples missing
entirely (no valid frame at all) just before it.

`BusMap` (canfdi.bus.dbc) decodes the frames; `SampleAssembler` is the streaming state machine:
`SampleAssembler.push` takes one frame (timestamps are passed in, nothing here reads a clock or
does I/O) and returns its status and the sample it completed. `SampleAssembler.push_batch` and
`assemble_batch` (a recorded log) take a `FrameBlock` with a vectorised decode; runs of regular
periods, whose outcome the state machine's rules fix in advance, are assembled with numpy too,
and every other frame goes through the same state machine, so replay and live runs see
identical samples and statistics.

Frame statuses (canfdi.bus.frames ``STATUS_NAMES``, int8 codes in the batch forms):

=============== ============================================================================
``ok``          a drive frame accepted into the pending sample
``monitor``     a valid frame of the monitor's own ``FDI_*`` messages: known, not a sample's
``unused``      a valid frame of a DBC message that carries no model signal (not a sample's),
                or a remote request for a DBC message (a master polling it: no data)
``unknown_id``  an 11-bit ID the DBC does not define (after the drives' node ids)
``extended``    a 29-bit (extended) ID the DBC does not define
``remote``      a remote transmission request for an ID the DBC does not define
``error_frame`` a bus error frame
``fd``          a CAN FD frame of no FD message (or a classic frame of an FD message)
``dlc``         wrong payload length for the message
``crc``         the message's E2E check failed (CRC, or a counter out of its range)
``duplicate``   the same message and counter again while that sample is held
``stale``       a counter older than the pending sample's (a late or replayed frame)
``jump``        a counter further ahead than the time since the last frame allows (the drive
                sends one sample per period), not confirmed by the next frame: a random frame
                that passed the 8-bit CRC, which would otherwise open a sample of garbage
``time_jump``   a timestamp further from the drive's time than the bound allows, not confirmed
                as a step of the clock by the frames after it (canfdi.bus.timegate)
``implausible`` a mapped value outside its signal's range (the DBC's, or the config's
                ``bus.map.<name>.range``): data without protection (CANopen has no CRC) that
                no drive sends
``saturated``   a mapped value at a limit of what its signal can carry (the DBC's
                [minimum|maximum] within the raw range; a limit at 0 excepted): the sender
                clipped it, so it says only that the quantity is at or beyond the limit, and a
                model fed it sees a fault that is not there
=============== ============================================================================

The first three are valid; every other status is counted by reason and never enters a sample.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

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
from canfdi.core.settings import ConfigError

__all__ = ["AssembledLog", "SampleAssembler", "assemble_batch"]

(_OK, _MONITOR, _UNUSED, _UNKNOWN_ID, _EXTENDED, _REMOTE, _ERROR_FRAME, _FD, _DLC, _CRC,
 _DUPLICATE, _STALE, _JUMP, _TIME_JUMP, _IMPLAUSIBLE, _SATURATED) = range(len(STATUS_NAMES))

# Fewest accepted drive frames push_batch sends through the state machine at a time (unless a
# regular run can take over), and fewest periods of a run it assembles with numpy: below these
# the numpy calls around them cost more than the machine's ~2 us a frame (measured).
_SLOW_SPAN = 32
_FAST_MIN_PERIODS = 4
# Periods a counter may run ahead of the clock (jitter, a burst after the drive's transmit queue
# was held up) before a forward step needs a second frame to confirm it.
_JUMP_SLACK = 3
# The compiled machine keeps the slots seen as bits of an int64.
_MACHINE_SLOTS = 62
_I64 = (-(1 << 63), (1 << 63) - 1)

# Samples assembled by push_batch, a run at a time: k, timestamp_ns, gap (B,) int64 and the
# flat [u, z] rows (B, p + q) float64.
_Block = tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], NDArray[np.float64]]


class AssembledLog(NamedTuple):
    """Samples and frame statuses of a batch of frames.

    k : (M,) int64 unwrapped sample indices; timestamp_ns : (M,) int64, arrival of each
    sample's last frame; u : (M, p), z : (M, q) float64 in the model's order, NaN for the
    signals of a broken sample's lost messages; gap : (M,) int64 samples missing entirely
    before each; statuses : (N,) int8 codes into `STATUS_NAMES`, one per frame; stats : the
    assembler's `SampleAssembler.stats` after the batch.

    Examples
    --------
    The shipped dc_motor config's drive: DRIVE_CMD (0x104: V), DRIVE_CURRENTS (0x105: i_f, i_a,
    i_f_plus_i_a) and DRIVE_SPEED (0x106: omega_r), each with canfdi's CRC and counter; one
    period's frames, counter 0:

    >>> from canfdi.bus.dbc import BusMap
    >>> from canfdi.bus.e2e import protect
    >>> from canfdi.core.settings import BusConfig, MonitorConfig
    >>> config = MonitorConfig.of_bus("dc_motor", ["V"], ["i_f", "i_a", "i_f_plus_i_a", "omega_r"],
    ...                               BusConfig(dbc="motor_drive"))
    >>> bus_map = BusMap.from_config(config)
    >>> cmd = protect(0x104, bytes(2) + (1200).to_bytes(2, "little") + bytes(4), 0)
    >>> currents = protect(0x105, bytes(2) + bytes.fromhex("f401b80bac0d"), 0)
    >>> speed = protect(0x106, bytes(2) + (10000).to_bytes(2, "little"), 0)
    >>> import can
    >>> from canfdi.bus.frames import FrameBlock
    >>> block = FrameBlock.from_messages(
    ...     [can.Message(timestamp=1.0 + 0.00013 * i, arbitration_id=frame_id, data=data,
    ...                  is_extended_id=False)
    ...      for i, (frame_id, data) in enumerate([(0x104, cmd), (0x105, currents),
    ...                                            (0x106, speed), (0x7FF, bytes(8))])])
    >>> log = SampleAssembler(bus_map, dt=0.01).push_batch(block)
    >>> log.k.tolist(), log.u.tolist(), log.z.tolist(), log.gap.tolist()
    ([0], [[12.0]], [[0.5, 3.0, 3.5, 100.0]], [0])
    >>> [STATUS_NAMES[code] for code in log.statuses], log.stats["frames_invalid"]
    (['ok', 'ok', 'ok', 'unknown_id'], 1)
    """

    k: NDArray[np.int64]
    timestamp_ns: NDArray[np.int64]
    u: NDArray[np.float64]
    z: NDArray[np.float64]
    gap: NDArray[np.int64]
    statuses: NDArray[np.int8]
    stats: dict


class SampleAssembler:
    """Streaming assembly of samples from frames (pure: time comes in with each frame).

    Parameters
    ----------
    bus_map : the compiled DBC mapping.
    dt : control period in seconds (> 0); used only to unwrap the 8-bit counter across
        outages longer than 128 periods.

    Notes
    -----
    One sample is pending at a time. A valid drive frame's counter c is unwrapped against the
    latest sample index K (its counter ``K mod 256``, last frame at time t0) as
    ``k = K + d + 256 n`` with ``d = (c - K) mod 256`` and ``n = round((elapsed - d) / 256)``,
    ``elapsed = (t - t0) / dt`` periods (clamped at 0), n >= -1: the candidate whose expected
    arrival time is nearest. With little elapsed time this is the counter rule (a forward step
    d <= 128 is a new sample, d in (128, 255] is stale); after an outage of more than 128
    periods the timestamps say how many wraps the counter made. k < K is "stale", k == K joins
    the pending sample (or is a "duplicate"), k > K closes the pending sample as broken if it
    is incomplete and opens sample k.

    Examples
    --------
    The shipped dc_motor config's drive: DRIVE_CMD (0x104: V), DRIVE_CURRENTS (0x105: i_f, i_a,
    i_f_plus_i_a) and DRIVE_SPEED (0x106: omega_r), each with canfdi's CRC and counter; one
    period's frames, counter 0:

    >>> from canfdi.bus.dbc import BusMap
    >>> from canfdi.bus.e2e import protect
    >>> from canfdi.core.settings import BusConfig, MonitorConfig
    >>> config = MonitorConfig.of_bus("dc_motor", ["V"], ["i_f", "i_a", "i_f_plus_i_a", "omega_r"],
    ...                               BusConfig(dbc="motor_drive"))
    >>> bus_map = BusMap.from_config(config)
    >>> cmd = protect(0x104, bytes(2) + (1200).to_bytes(2, "little") + bytes(4), 0)
    >>> currents = protect(0x105, bytes(2) + bytes.fromhex("f401b80bac0d"), 0)
    >>> speed = protect(0x106, bytes(2) + (10000).to_bytes(2, "little"), 0)
    >>> assembler = SampleAssembler(bus_map, dt=0.01)
    >>> assembler.push(0, 0x104, cmd), assembler.push(130_000, 0x105, currents)
    (('ok', []), ('ok', []))
    >>> status, [sample] = assembler.push(260_000, 0x106, speed)
    >>> status, sample.k, sample.u.tolist(), sample.z.tolist()
    ('ok', 0, [12.0], [0.5, 3.0, 3.5, 100.0])

    A repeated frame is no new sample:

    >>> assembler.push(390_000, 0x106, speed), assembler.stats["duplicates"]
    (('duplicate', []), 1)
    """

    def __init__(self, bus_map: BusMap, dt: float) -> None:
        if not isinstance(dt, int | float) or not math.isfinite(dt) or dt <= 0:
            raise ValueError(f"dt: the control period must be a finite number of seconds > 0, "
                             f"got {dt!r}")
        if bus_map.counter_modulus is None:
            without = [lay.name for lay, e2e in zip(bus_map.layouts, bus_map.e2e, strict=True)
                       if e2e.counter_modulus is None]
            raise ConfigError("bus.clock.kind", "a counter clock needs an alive counter in every "
                              f"mapped message, of one modulus; {', '.join(without) or 'they'} "
                              "do not have one (their E2E profile): use a trigger or grid clock")
        self.bus_map = bus_map
        self._mod = int(bus_map.counter_modulus)
        # The fast path takes frames at most this many periods apart: the unwrap rule then
        # rounds n to 0 (the plain counter rule) with a full period to spare for float rounding.
        self._fast_max = self._mod // 2 - 1
        self.dt = float(dt)
        self._dt_ns = self.dt * 1e9
        self._p = bus_map.p
        self._dests = bus_map._dests
        self._full = (1 << len(bus_map.layouts)) - 1
        # The pending sample: flat [u, z] values, slots seen (bit mask), open or closed.
        self._buffer = [0.0] * (bus_map.p + bus_map.q)
        self._seen = 0
        self._open = False
        self._k = -1  # latest sample index started (-1: no frame yet)
        self._t_ref = 0  # arrival of the latest accepted frame, ns
        self._last_complete = -1
        self._last_delivered = -1  # latest sample handed out, complete or broken
        self._last_gap = 0  # gap of the sample _accept just completed
        self._partial: tuple[int, int, int, list[float]] | None = None  # broken, to hand out
        self._jump: int | None = None  # an unconfirmed counter jump: the sample it would open
        self._counts = [0] * len(STATUS_NAMES)
        self._complete = 0
        self._broken = 0
        self._missing = 0
        # Within a counter's modulus the counter says how many periods passed.
        self.gate = TimeGate(round(max(self._mod, MIN_BOUND_PERIODS) * self._dt_ns))
        self._dest = dest_table(self._dests)
        # The state machine's run over a stretch of frames in compiled code, when
        # canfdi.core.kernel installed its C core's (the same verdicts and samples); None:
        # this module's Python, frame by frame.
        self.machine: Callable[..., tuple] | None = None

    def c_params(self) -> dict:
        """What the C core's counter clock and time gate take besides the frames (the fields
        of canfdi/_c/drive.h's cfdi_drive_tables, for `canfdi codegen`): the counter's modulus,
        the period (ns), the jump slack, the (slots, fields) destination table, and the gate's
        bound (ns) and confirming frames."""
        return {"mod": self._mod, "dt_ns": self._dt_ns, "slack": float(_JUMP_SLACK),
                "dest": self._dest, "gate_bound": self.gate.bound,
                "gate_confirm": self.gate.confirm}

    @property
    def stats(self) -> dict:
        """Counters since construction.

        Returns
        -------
        dict with frames_received, frames_valid, frames_invalid, invalid_by_reason (every
        invalid status -> count, zeros included), samples_complete, samples_broken (started but
        never completed, including one closed by `flush`; delivered with NaN for the signals of
        their missing messages), samples_missing (no valid frame at all), duplicates.
        """
        return frame_counters(self._counts, self._complete, self._broken, self._missing,
                              len(self.gate.steps))

    def push(
        self,
        timestamp_ns: int,
        frame_id: int,
        data: bytes | bytearray,
        *,
        is_extended: bool = False,
        is_remote: bool = False,
        is_error: bool = False,
        is_fd: bool = False,
    ) -> tuple[str, list[Sample]]:
        """Take one received frame.

        Parameters
        ----------
        timestamp_ns : arrival time, integer nanoseconds (any epoch, the same for all frames).
        frame_id : arbitration ID.
        data : (dlc,) payload.
        is_extended, is_remote, is_error, is_fd : python-can's Message flags.

        Returns
        -------
        status : one of `STATUS_NAMES`.
        samples : the samples this frame delivered, in order: a broken sample it closed (NaN
            for the missing signals) and/or the sample it completed.
        """
        flags = (is_extended * FLAG_EXTENDED | is_remote * FLAG_REMOTE | is_error * FLAG_ERROR
                 | is_fd * FLAG_FD)
        status, slot, values, counter = self.bus_map.decode_frame(frame_id, data, flags)
        if status != "ok":
            self._counts[STATUS_CODES[status]] += 1
            return status, []
        timestamp_ns = self.gate.step(timestamp_ns)
        if timestamp_ns is None:
            self._counts[_TIME_JUMP] += 1
            return "time_jump", []
        code = self._place(slot, counter, timestamp_ns)
        self._counts[code] += 1
        out = self._take_partial()
        if code == _OK:
            buffer = self._buffer
            for dest, value in zip(self._dests[slot], values, strict=True):
                buffer[dest] = value
            if self._accept(slot):
                out.append(self._sample(self._k, timestamp_ns, self._last_gap, buffer))
        return STATUS_NAMES[code], out

    def flush(self) -> list[Sample]:
        """End of stream: a pending incomplete sample is closed as broken and delivered."""
        if self._open:
            self._close_broken()
        return self._take_partial()

    def _close_broken(self) -> None:
        """The pending sample will not complete: keep it, NaN for its missing messages."""
        self._open = False
        self._broken += 1
        row = list(self._buffer)
        nan = math.nan
        for slot, dests in enumerate(self._dests):
            if not self._seen >> slot & 1:
                for dest in dests:
                    row[dest] = nan
        gap = 0 if self._last_delivered < 0 else self._k - self._last_delivered - 1
        self._last_delivered = self._k
        self._partial = (self._k, self._t_ref, gap, row)

    def _take_partial(self) -> list[Sample]:
        if self._partial is None:
            return []
        k, t, gap, row = self._partial
        self._partial = None
        return [self._sample(k, t, gap, row)]

    def _sample(self, k: int, t: int, gap: int, row: list[float]) -> Sample:
        """A Sample of flat [u, z] values (copied)."""
        p = self._p
        return Sample(k=k, timestamp_ns=t, u=np.array(row[:p]), z=np.array(row[p:]), gap=gap)

    def push_batch(self, block: FrameBlock) -> AssembledLog:
        """`push` for a block of frames, in order, with a vectorised decode.

        Parameters
        ----------
        block : the frames (`canfdi.bus.frames.FrameBlock`); their flags decide error, remote,
            FD and extended frames as `push` does.

        Returns
        -------
        AssembledLog of the samples completed by these frames; the state carries over to the
        next call exactly as if the frames had been pushed one by one (no `flush`).

        Notes
        -----
        Runs of regular periods skip the per-frame state machine: the used drive messages once
        each in slot (ID) order, one counter per period and the next one in the next period,
        each frame less than 127 periods after the one before, starting when the latest sample
        is complete, and at least 4 periods long. Their samples are assembled with numpy,
        several million frames a second; any other order, a defect, a pause or a counter jump
        sends the frames up to the next such run through the state machine (about 2 us a
        frame). With the C kernel installed (``machine``) every frame goes through the compiled
        machine instead, some 10 M frames a second clean or damaged.
        """
        status, slot, values, counters = self.bus_map.decode_frames(block)
        drive = np.flatnonzero(status == _OK)
        timestamps_ns, dropped = self.gate.apply(block.t_ns, drive)
        if dropped.size:
            status[drive[dropped]] = _TIME_JUMP
            drive = np.delete(drive, dropped)
        blocks = self._assemble(drive, slot[drive], counters[drive], timestamps_ns, values,
                                status)
        # Every status is final now (the machine wrote its verdicts): count them in one go.
        for code, count in enumerate(np.bincount(status, minlength=len(STATUS_NAMES))):
            self._counts[code] += int(count)
        p = self._p
        if blocks:
            ks, times, gaps, flat = (np.concatenate(part) for part in zip(*blocks, strict=True))
        else:
            ks, times, gaps = (np.zeros(0, dtype=np.int64) for _ in range(3))
            flat = np.zeros((0, len(self._buffer)))
        return AssembledLog(k=ks, timestamp_ns=times, u=flat[:, :p], z=flat[:, p:], gap=gaps,
                            statuses=status, stats=self.stats)

    # -- batch assembly: regular runs vectorised, the rest through the state machine ---------

    def _assemble(
        self,
        drive: NDArray[np.intp],
        slots: NDArray[np.int16],
        counters: NDArray[np.int16],
        timestamps_ns: NDArray[np.integer],
        values: NDArray[np.float64],
        status: NDArray[np.int8],
    ) -> list[_Block]:
        """Run the accepted drive frames of a batch through the state machine, in order.

        Only these frames can change the state (every other status is final after the decode),
        so the sequence of drive frames is the whole input of the machine. Where it is in the
        state a completed sample K leaves (`_is_settled`) and the frames ahead are whole regular
        periods (`_regular_runs`) with the next counter, arriving soon enough, the machine's
        decisions are known in advance: each period is the next sample, complete, gap 0. Those
        periods are assembled with numpy (`_fast_run`); everything else goes through `_place`
        and `_accept` frame by frame (`_slow_run`).

        Parameters
        ----------
        drive : (D,) positions in the batch of the frames the decode found "ok" (drive frames).
        slots, counters : (D,) their slots and counters.
        timestamps_ns : (N,) arrival times of the whole batch.
        values : (N, n_signals_max) decoded values of the whole batch.
        status : (N,) int8 status codes; the machine's verdicts (duplicate, stale) are written
            into it.

        Returns
        -------
        list of (k, timestamp_ns, gap, [u, z] rows) blocks of samples, (B,), (B,), (B,),
        (B, p + q) each, in order.
        """
        blocks: list[_Block] = []
        n = drive.size
        if n == 0:
            return blocks
        if self.machine is not None and len(self._dests) <= _MACHINE_SLOTS:
            # The compiled machine takes every frame at its own speed: regular runs need no
            # numpy pass of their own (the same decisions: a run is what the machine decides).
            block, _ = self._machine_run(drive, slots, counters, timestamps_ns[drive], values,
                                         status)
            return [] if block is None else [block]
        times = timestamps_ns[drive]
        starts, groups = self._regular_runs(slots, counters, times)
        m = len(self._dests)
        pos = 0
        while pos < n:
            j = int(np.searchsorted(starts, pos))
            if j < starts.size and starts[j] == pos and self._is_settled(int(counters[pos]),
                                                                          int(times[pos])):
                g = int(groups[j])
                blocks.append(self._fast_run(drive[pos: pos + g * m], times, pos, g, values))
                pos += g * m
                continue
            # The machine over a stretch long enough to pay for the numpy calls around it, up
            # to where a regular run starts; it hands back early where one can take over.
            far = int(np.searchsorted(starts, pos + _SLOW_SPAN))
            stop = int(starts[far]) if far < starts.size else n
            takeover = set((starts[j:far] - pos).tolist())
            block, used = self._slow_run(drive[pos:stop], slots[pos:stop], counters[pos:stop],
                                         times[pos:stop], values, status, takeover)
            if block is not None:
                blocks.append(block)
            pos += used
        return blocks

    def _regular_runs(
        self, slots: NDArray[np.int16], counters: NDArray[np.int16], times: NDArray[np.integer]
    ) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        """Where whole regular periods begin in a sequence of accepted drive frames.

        A frame is *linked* to the one before it when it is the next slot with the same counter,
        or slot 0 after slot M-1 with the counter + 1 (mod 256), and it arrived less than
        `_FAST_MAX_ELAPSED` periods after it (earlier is fine: the machine clamps at 0).

        Parameters
        ----------
        slots, counters : (D,) of the accepted drive frames, in order.
        times : (D,) their arrival times, ns.

        Returns
        -------
        starts : (S,) ascending positions of slot-0 frames followed by whole periods of linked
            frames, `_FAST_MIN_PERIODS` or more.
        groups : (S,) the number of whole periods of linked frames from each.
        """
        m = len(self._dests)
        n = slots.size
        none = np.zeros(0, dtype=np.intp)
        if m == 0 or n < m:
            return none, none
        if times.dtype.kind == "u" and times.max() > np.iinfo(np.int64).max:
            return none, none  # beyond int64: leave such times to the machine's Python ints
        t = times.astype(np.int64, copy=False)
        s = slots.astype(np.int64)
        c = counters.astype(np.int64)
        same_period = (s[1:] == s[:-1] + 1) & (c[1:] == c[:-1])
        next_period = (s[1:] == 0) & (s[:-1] == m - 1) & (c[1:] == (c[:-1] + 1) % self._mod)
        diff = t[1:] - t[:-1]
        # int64 wraps silently; a wrapped difference would hide a huge (or negative) one.
        wrapped = ((t[1:] ^ t[:-1]) & (t[1:] ^ diff)) < 0
        soon = ~wrapped & (diff < self._fast_max * self._dt_ns)
        linked = (same_period | next_period) & soon
        # Run ends: the positions whose link to the previous frame is broken, and the end.
        breaks = np.append(np.flatnonzero(~linked) + 1, n)
        heads = np.flatnonzero(s == 0)
        ends = breaks[np.searchsorted(breaks, heads, side="right")]
        groups = (ends - heads) // m
        whole = groups >= _FAST_MIN_PERIODS
        return heads[whole], groups[whole]

    def _is_settled(self, counter: int, t: int) -> bool:
        """Whether the machine would make a regular run starting with this frame samples K+1, ...

        Parameters
        ----------
        counter : the run's first frame's counter.
        t : its arrival time, ns.

        Returns
        -------
        True when the latest sample K is complete (then it is not pending either: a sample only
        opens with a new K, so no pending sample can break or be joined, and the next sample's
        gap is 0), the frame carries counter K + 1 and it arrived less than `_FAST_MAX_ELAPSED`
        periods after the latest accepted frame, so that `_place` unwraps it to K + 1 (n = 0).
        """
        k = self._k
        return (k >= 0 and self._last_complete == k and counter == (k + 1) % self._mod
                and t - self._t_ref < self._fast_max * self._dt_ns)

    def _fast_run(
        self,
        rows: NDArray[np.intp],
        times: NDArray[np.integer],
        pos: int,
        g: int,
        values: NDArray[np.float64],
    ) -> _Block:
        """Assemble g whole regular periods at once, leaving the state the machine would.

        Parameters
        ----------
        rows : (g M,) positions in the batch of the periods' frames, slot order per period.
        times : (D,) arrival times of the accepted drive frames; the run starts at ``pos``.
        pos : position of the run's first frame among the accepted drive frames.
        g : number of periods.
        values : (N, n_signals_max) decoded values of the whole batch.

        Returns
        -------
        (k, timestamp_ns, gap, [u, z] rows) of the g samples: (g,), (g,), (g,), (g, p + q).
        """
        m = len(self._dests)
        # Positions no field writes keep the pending buffer's value, as in the machine; the
        # loop keeps its write order (slot by slot) should two fields share a position. Each
        # value is one gather of its slot's frames (rows s, s + M, ...) from its column.
        flat = np.empty((g, len(self._buffer)))
        flat[:] = self._buffer
        for s, dests in enumerate(self._dests):
            frames = rows[s::m]
            for col, dest in enumerate(dests):
                flat[:, dest] = values[frames, col]
        k0 = self._k + 1
        ks = np.arange(k0, k0 + g, dtype=np.int64)
        # Each sample is completed by its period's last frame (slot M-1).
        done = times[pos + m - 1: pos + g * m: m].astype(np.int64)
        self._k = self._last_complete = self._last_delivered = k0 + g - 1
        self._t_ref = int(done[-1])
        self._seen = self._full
        self._open = False
        self._jump = None
        self._last_gap = 0
        self._complete += g
        self._buffer[:] = flat[-1].tolist()
        return ks, done, np.zeros(g, dtype=np.int64), flat

    def _slow_run(
        self,
        rows: NDArray[np.intp],
        slots: NDArray[np.int16],
        counters: NDArray[np.int16],
        times: NDArray[np.integer],
        values: NDArray[np.float64],
        status: NDArray[np.int8],
        takeover: set[int],
    ) -> tuple[_Block | None, int]:
        """Accepted drive frames through the state machine, one by one (as `push` does).

        Parameters
        ----------
        rows : (R,) positions in the batch of the frames.
        slots, counters, times : (R,) of the frames.
        values : (N, n_signals_max) decoded values of the whole batch.
        status : (N,) int8 status codes; duplicate and stale verdicts are written into it.
        takeover : positions (into rows) where a regular run starts: the machine stops before
            one when it has just completed a sample and `_is_settled` says the run is fast.

        Returns
        -------
        block : (k, timestamp_ns, gap, [u, z] rows) of the samples completed, or None.
        used : how many of the frames were taken (R, or the position where it stopped).
        """
        # Only without a compiled machine: `_assemble` hands every frame to one when installed.
        return self._python_run(rows, slots, counters, times, values, status, takeover)

    _STATE = ("_k", "_t_ref", "_seen", "_open", "_last_complete", "_last_delivered",
              "_last_gap", "_jump", "_complete", "_broken", "_missing")

    def _machine_run(
        self,
        rows: NDArray[np.intp],
        slots: NDArray[np.int16],
        counters: NDArray[np.int16],
        times: NDArray[np.integer],
        values: NDArray[np.float64],
        status: NDArray[np.int8],
    ) -> tuple[_Block | None, int]:
        """`_python_run` over every frame on the installed compiled machine: the state in, the
        frames through, the state out; where it stops short (times or indices beyond what it
        takes), the rest goes through `_python_run`."""
        k, t_ref, seen, is_open, last_c, last_d, gap, jump, comp, broken, missing = (
            getattr(self, name) for name in self._STATE)
        state = [k, t_ref, seen, int(is_open), last_c, last_d, gap, int(jump is not None),
                 jump or 0, comp, broken, missing]
        if not all(_I64[0] <= int(v) <= _I64[1] for v in state):
            return self._python_run(rows, slots, counters, times, values, status, set())
        n = len(rows)
        st = np.array(state, dtype=np.int64)
        buffer = np.array(self._buffer, dtype=np.float64)
        got = self.machine(st, buffer, rows, slots, counters, times, values, status,
                           self._dest, self._mod, self._dt_ns, float(_JUMP_SLACK))
        (ks, done, gaps, samples), used = got
        (self._k, self._t_ref, self._seen, is_open, self._last_complete, self._last_delivered,
         self._last_gap, jump_set, jump, self._complete, self._broken,
         self._missing) = st.tolist()
        self._open = bool(is_open)
        self._jump = jump if jump_set else None
        self._buffer[:] = buffer.tolist()
        block = (ks, done, gaps, samples) if len(ks) else None
        if used == n:
            return block, used
        later, more = self._python_run(rows[used:], slots[used:], counters[used:],
                                       times[used:], values, status, set())
        if block is None or later is None:
            return block if later is None else later, used + more
        return tuple(np.concatenate([a, b]) for a, b in zip(block, later, strict=True)), \
            used + more

    def _python_run(
        self,
        rows: NDArray[np.intp],
        slots: NDArray[np.int16],
        counters: NDArray[np.int16],
        times: NDArray[np.integer],
        values: NDArray[np.float64],
        status: NDArray[np.int8],
        takeover: set[int],
    ) -> tuple[_Block | None, int]:
        """`_slow_run` in Python, frame by frame (the reference)."""
        ks: list[int] = []
        done: list[int] = []
        gaps: list[int] = []
        samples: list[list[float]] = []
        buffer, dests = self._buffer, self._dests
        counter_list, time_list = counters.tolist(), times.tolist()
        used = len(counter_list)
        for r, (i, s, c, t, vals) in enumerate(zip(rows.tolist(), slots.tolist(), counter_list,
                                                   time_list, values[rows].tolist(),
                                                   strict=True)):
            code = self._place(s, c, t)
            if self._partial is not None:
                pk, pt, pgap, prow = self._partial
                self._partial = None
                ks.append(pk)
                done.append(pt)
                gaps.append(pgap)
                samples.append(prow)
            if code != _OK:
                status[i] = code
                continue
            # Rows are NaN-padded to n_signals_max; zip stops at this slot's own fields.
            for dest, value in zip(dests[s], vals, strict=False):
                buffer[dest] = value
            if self._accept(s):
                ks.append(self._k)
                done.append(t)
                gaps.append(self._last_gap)
                samples.append(buffer[:])
                # Only a completion can settle the state: the one moment to hand over.
                if r + 1 in takeover and self._is_settled(counter_list[r + 1],
                                                          time_list[r + 1]):
                    used = r + 1
                    break
        if not ks:
            return None, used
        return (np.array(ks, dtype=np.int64), np.array(done, dtype=np.int64),
                np.array(gaps, dtype=np.int64),
                np.array(samples, dtype=float).reshape(len(samples), len(buffer))), used

    # -- the state machine (shared by push and push_batch) ------------------------------------

    def _place(self, slot: int, counter: int, t: int) -> int:
        """Status code of a valid drive frame; on _OK the pending sample is the frame's."""
        k_cur = self._k
        if k_cur < 0:
            # The first frame ever: its counter is its sample index.
            k = counter
        else:
            d = (counter - k_cur) % self._mod
            elapsed = (t - self._t_ref) / self._dt_ns
            if elapsed < 0.0:
                elapsed = 0.0
            # floor(x + 0.5): rounds halves up, so d = 128 with no elapsed time counts as
            # forward; n >= -1 holds because elapsed >= 0 and d <= 255.
            n = math.floor((elapsed - d) / self._mod + 0.5)
            k = k_cur + d + self._mod * n
            if k == k_cur:
                if self._seen >> slot & 1:
                    return _DUPLICATE
                if not self._open:
                    return _STALE
                self._t_ref = t
                self._jump = None
                return _OK
            if k < k_cur:
                return _STALE
            if k - k_cur > elapsed + _JUMP_SLACK:
                # Ahead of the clock: garbage that passed the CRC (1 in 256 random frames), or
                # a drive restarted with a new count, which its next frame confirms (same or
                # next sample).
                if self._jump is None or not 0 <= k - self._jump <= 1:
                    self._jump = k
                    return _JUMP
            if self._open:
                self._close_broken()
            self._missing += k - k_cur - 1
        self._k = k
        self._seen = 0
        self._open = True
        self._t_ref = t
        self._jump = None
        return _OK

    def _accept(self, slot: int) -> bool:
        """Mark the slot seen (its values are in the buffer); True when that completes k."""
        self._seen |= 1 << slot
        if self._seen != self._full:
            return False
        self._open = False
        last = self._last_delivered
        self._last_gap = 0 if last < 0 else self._k - last - 1
        self._last_complete = self._last_delivered = self._k
        self._complete += 1
        return True


def dest_table(dests: tuple[tuple[int, ...], ...]) -> NDArray[np.int64]:
    """(slots, most fields) int64: each slot's fields' positions in a sample row, -1 beyond."""
    cols = max((len(d) for d in dests), default=0)
    table = np.full((len(dests), cols), -1, dtype=np.int64)
    for s, row in enumerate(dests):
        table[s, :len(row)] = row
    return table


def assemble_batch(bus_map: BusMap, dt: float, block: FrameBlock) -> AssembledLog:
    """Assemble a whole recorded log (offline replay).

    Parameters
    ----------
    bus_map : the compiled DBC mapping.
    dt : control period, seconds.
    block : the log's frames (`canfdi.bus.frames.FrameBlock`).

    Returns
    -------
    AssembledLog: the same samples, per-frame statuses and stats as pushing every frame to a
    fresh `SampleAssembler` one by one and then calling `SampleAssembler.flush` (a sample left
    incomplete at the end of the log is delivered as broken).
    """
    assembler = SampleAssembler(bus_map, dt)
    log = assembler.push_batch(block)
    last = assembler.flush()
    if last:
        (s,) = last
        log = log._replace(
            k=np.append(log.k, s.k), timestamp_ns=np.append(log.timestamp_ns, s.timestamp_ns),
            u=np.vstack([log.u, s.u[None, :]]), z=np.vstack([log.z, s.z[None, :]]),
            gap=np.append(log.gap, s.gap))
    return log._replace(stats=assembler.stats)
