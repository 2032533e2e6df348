"""`TopicWrites`: the recorder's write methods for row topics and canfdi's own messages.

`TopicWrites.write_row` and `TopicWrites.write_rows` buffer the rows of any row topic of
canfdi.io.rowtopics; samples and residuals have their own forms of them, checked against their
names. Estimates, events, status and log lines are single JSON messages, written at once.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from canfdi.io.blocks import check_column, check_matrix, encode_message, float_row, stamp
from canfdi.io.schemas import (
    LOG_LEVELS,
    TOPIC_ESTIMATES,
    TOPIC_EVENTS,
    TOPIC_LOG,
    TOPIC_RESIDUALS,
    TOPIC_SAMPLES,
    TOPIC_STATUS,
)

if TYPE_CHECKING:
    from canfdi.core.records import FaultEvent, Sample

__all__ = ["TopicWrites"]


class TopicWrites:
    """canfdi's topics, written through the primitives of `McapRecorder` (the one class that
    inherits this): ``_begin_write()`` (the clock's now, after a due flush), ``_row_channel``
    (a row topic's channel, named and of the drive given), ``_append_row`` and ``_add_rows``
    (a row, or checked columns, buffered) and ``_write_message`` (one encoded message, at once)."""

    def write_row(self, topic: str, timestamp_ns: int, ints: Sequence[int],
                  groups: Sequence[ArrayLike], names: Sequence[Sequence[str]],
                  drive: str | None = None) -> None:
        """Buffer one row of a row topic (canfdi.io.rowtopics), copied.

        Parameters
        ----------
        topic : str
            A registered row topic (`ROW_LAYOUTS`).
        timestamp_ns : int
            The row's time.
        ints : sequence of int
            The layout's integer fields, in order.
        groups : sequence of array_like
            The layout's groups of numbers, in order, each as long as its name list.
        names : sequence of sequences of str
            The layout's name lists; a change writes the buffered rows first.
        drive : str, optional
            The drive whose row it is; a change writes the buffered rows first.

        Raises
        ------
        ValueError
            After `close`, or for a row that does not match the layout or the names.
        """
        now = self._begin_write()
        channel = self._row_channel(topic, names, drive, now)
        layout = channel.encoder.layout
        widths = layout.widths(channel.encoder.names)
        values = [float_row(group) for group in groups]
        if len(ints) != len(layout.ints) or [len(v) for v in values] != list(widths):
            raise ValueError(f"a {topic} row has fields {layout.columns[1:]} of widths "
                             f"{widths}, got {len(ints)} integers and groups "
                             f"{[len(v) for v in values]}")
        self._append_row(channel, (timestamp_ns, *ints, *values), now)

    def write_rows(self, topic: str, t_ns: ArrayLike, ints: Sequence[ArrayLike],
                   groups: Sequence[ArrayLike], names: Sequence[Sequence[str]],
                   drive: str | None = None) -> None:
        """Buffer N rows of a row topic (canfdi.io.rowtopics), vectorised (copied).

        Parameters
        ----------
        topic : str
            A registered row topic (`ROW_LAYOUTS`).
        t_ns : (N,) int
            The rows' times.
        ints : sequence of (N,) int
            The layout's integer fields, in order.
        groups : sequence of (N, width) float
            The layout's groups of numbers, in order, each as wide as its name list.
        names, drive
            As `write_row`.

        Raises
        ------
        ValueError
            After `close`, or for arrays of the wrong shape.
        """
        now = self._begin_write()
        channel = self._row_channel(topic, names, drive, now)
        layout = channel.encoder.layout
        if len(ints) != len(layout.ints) or len(groups) != len(layout.groups):
            raise ValueError(f"{topic} rows have fields {layout.columns[1:]}")
        n = len(np.asarray(t_ns))
        columns = [check_column(t_ns, n, "t_ns").astype(np.int64)]
        columns += [check_column(values, n, name).astype(np.int64)
                    for values, name in zip(ints, layout.ints, strict=True)]
        columns += [check_matrix(values, n, width, key) for values, (key, _), width in
                    zip(groups, layout.groups, layout.widths(channel.encoder.names),
                        strict=True)]
        self._add_rows(channel, tuple(columns), now)

    def write_sample(
        self, sample: Sample, input_names: Sequence[str], output_names: Sequence[str],
        drive: str | None = None,
    ) -> None:
        """Buffer a decoded sample for `TOPIC_SAMPLES` (a cheap append).

        Parameters
        ----------
        sample : Sample
            The sample; ``u`` and ``z`` are named by ``input_names`` and ``output_names``. Its
            arrays are kept until the block is written, so they must not be modified (a
            Sample is a frozen record).
        input_names, output_names : sequence of str
            The model's input and output names, in the sample's order. A change of names
            writes the buffered samples first.
        drive : str, optional
            The drive whose sample it is (several drives on one bus); a change of drive
            writes the buffered samples first.

        Raises
        ------
        ValueError
            After `close`, or if ``u`` or ``z`` does not match the names.
        """
        now = self._begin_write()
        channel = self._row_channel(TOPIC_SAMPLES, (input_names, output_names), drive, now)
        inputs, outputs = channel.encoder.names
        u, z = sample.u, sample.z
        if len(u) != len(inputs) or len(z) != len(outputs):
            raise ValueError(
                f"sample has {len(u)} inputs and {len(z)} outputs for names "
                f"{inputs} and {outputs}"
            )
        self._append_row(channel, (sample.timestamp_ns, sample.k, sample.gap, u, z), now)

    def write_samples(
        self,
        k: ArrayLike,
        t_ns: ArrayLike,
        U: ArrayLike,
        Z: ArrayLike,
        gap: ArrayLike,
        input_names: Sequence[str],
        output_names: Sequence[str],
        drive: str | None = None,
    ) -> None:
        """Buffer a block of decoded samples for `TOPIC_SAMPLES`, vectorised (copied).

        Parameters
        ----------
        k : (N,) int
            Sample indices.
        t_ns : (N,) int
            Sample times, ns since the epoch.
        U : (N, p) float
            Inputs, named by ``input_names``.
        Z : (N, q) float
            Outputs, named by ``output_names``.
        gap : (N,) int
            Samples lost just before each one.
        input_names, output_names : sequence of str
            The model's input and output names.
        drive : str, optional
            The drive whose samples they are (as `write_sample`).

        Raises
        ------
        ValueError
            After `close`, or for arrays of the wrong shape.
        """
        now = self._begin_write()
        channel = self._row_channel(TOPIC_SAMPLES, (input_names, output_names), drive, now)
        inputs, outputs = channel.encoder.names
        n = len(np.asarray(k))
        k = check_column(k, n, "k").astype(np.int64)
        t_ns = check_column(t_ns, n, "t_ns").astype(np.int64)
        gap = check_column(gap, n, "gap").astype(np.int64)
        U, Z = check_matrix(U, n, len(inputs), "U"), check_matrix(Z, n, len(outputs), "Z")
        self._add_rows(channel, (t_ns, k, gap, U, Z), now)

    def write_residuals(
        self,
        timestamp_ns: int,
        k: int,
        names: Sequence[str],
        r: ArrayLike,
        normalized: ArrayLike,
        statistic: ArrayLike,
        drive: str | None = None,
    ) -> None:
        """Buffer one sample's residuals for `TOPIC_RESIDUALS` (a cheap append, copied).

        Parameters
        ----------
        timestamp_ns : int
            Time of the sample.
        k : int
            Sample index.
        names : sequence of str
            Residual names; ``r``, ``normalized`` and ``statistic`` are in this order. A
            change of names writes the buffered rows first.
        r : array_like
            Raw residual values.
        normalized : array_like
            Residuals divided by their standard deviation.
        statistic : array_like
            Page-Hinkley statistic max(g+, g-) of every residual.
        drive : str, optional
            The drive whose residuals they are; a change writes the buffered rows first.

        Raises
        ------
        ValueError
            After `close`, or if a row does not match the names.
        """
        now = self._begin_write()
        channel = self._row_channel(TOPIC_RESIDUALS, (names,), drive, now)
        (listed,) = channel.encoder.names
        r, normalized, statistic = float_row(r), float_row(normalized), float_row(statistic)
        m = len(listed)
        if len(r) != m or len(normalized) != m or len(statistic) != m:
            raise ValueError(f"residual rows do not match the {m} names {listed}")
        self._append_row(channel, (timestamp_ns, k, r, normalized, statistic), now)

    def write_residual_rows(
        self,
        k: ArrayLike,
        t_ns: ArrayLike,
        names: Sequence[str],
        R: ArrayLike,
        Rn: ArrayLike,
        stat: ArrayLike,
        drive: str | None = None,
    ) -> None:
        """Buffer many samples' residuals for `TOPIC_RESIDUALS`, vectorised (copied).

        Parameters
        ----------
        k : (N,) int
            Sample indices.
        t_ns : (N,) int
            Sample times, ns since the epoch.
        names : sequence of str
            The m residual names.
        R, Rn, stat : (N, m) float
            Raw residuals, normalized residuals, Page-Hinkley statistics.
        drive : str, optional
            The drive whose residuals they are (as `write_residuals`).

        Raises
        ------
        ValueError
            After `close`, or for arrays of the wrong shape.
        """
        now = self._begin_write()
        channel = self._row_channel(TOPIC_RESIDUALS, (names,), drive, now)
        n, m = len(np.asarray(k)), len(channel.encoder.names[0])
        k = check_column(k, n, "k").astype(np.int64)
        t_ns = check_column(t_ns, n, "t_ns").astype(np.int64)
        R, Rn = check_matrix(R, n, m, "R"), check_matrix(Rn, n, m, "Rn")
        stat = check_matrix(stat, n, m, "stat")
        self._add_rows(channel, (t_ns, k, R, Rn, stat), now)

    def write_estimates(
        self,
        timestamp_ns: int,
        k: int,
        hypothesis: str,
        estimates: Mapping[str, float],
        variances: Mapping[str, float],
    ) -> None:
        """Record a hypothesis' running estimates on `TOPIC_ESTIMATES`.

        Parameters
        ----------
        timestamp_ns : int
            Time of the sample.
        k : int
            Sample index.
        hypothesis : str
            Which fault hypothesis the estimates belong to (e.g. ``"actuator:torque"``).
        estimates, variances : mapping of str to float
            The estimates and their variances, same keys.
        """
        message = {
            "timestamp": stamp(timestamp_ns),
            "k": k,
            "hypothesis": hypothesis,
            "estimates": dict(estimates),
            "variances": dict(variances),
        }
        self._write_message(TOPIC_ESTIMATES, timestamp_ns, encode_message(message))

    def write_event(self, event: FaultEvent) -> None:
        """Record a diagnoser conclusion on `TOPIC_EVENTS` (at ``event.timestamp_ns``; fields
        that are None are left out, so that each has one JSON type). An accepted or refined
        fault's estimates go on `TOPIC_ESTIMATES` too (hypothesis ``drive/target:name``)."""
        message = {"timestamp": stamp(event.timestamp_ns),
                   **{k: v for k, v in event.as_dict().items() if v is not None}}
        self._write_message(TOPIC_EVENTS, event.timestamp_ns, encode_message(message))
        if event.kind in ("accepted", "refined") and event.estimates:
            who = f"{event.drive}/" if event.drive else ""
            self.write_estimates(event.timestamp_ns, event.sample,
                                 f"{who}{event.target}:{event.name}", event.estimates,
                                 event.variances or {})

    def write_log(self, timestamp_ns: int, level: str, message: str, name: str = "canfdi",
                  file: str = "", line: int = 0) -> None:
        """Record a log line on `TOPIC_LOG` (``foxglove.Log``: Foxglove's Log panel).

        Parameters
        ----------
        timestamp_ns : int
            Its time (the drive's).
        level : {"debug", "info", "warning", "error", "fatal"}
            Its level.
        message : str
            The line.
        name : str
            Who says it (``"canfdi.left"``: the monitor of drive left).
        file, line : str, int
            Where in the source, for log records that know.
        """
        if level not in LOG_LEVELS:
            raise ValueError(f"log level must be one of {', '.join(LOG_LEVELS)}, got {level!r}")
        record = {"timestamp": stamp(timestamp_ns), "level": LOG_LEVELS[level],
                  "message": message, "name": name, "file": file, "line": int(line)}
        self._write_message(TOPIC_LOG, timestamp_ns, encode_message(record))

    def write_status(
        self,
        timestamp_ns: int,
        state: str,
        samples: int,
        frames: Mapping[str, int],
        active_faults: int,
    ) -> None:
        """Record the monitor's periodic status on `TOPIC_STATUS`.

        Parameters
        ----------
        timestamp_ns : int
            Time of the report.
        state : str
            The monitor's state (e.g. ``"running"``).
        samples : int
            Samples decoded so far.
        frames : mapping of str to int
            Frame counters by kind (e.g. ``{"ok": .., "crc": ..}``).
        active_faults : int
            Faults currently accepted and compensated.
        """
        message = {
            "timestamp": stamp(timestamp_ns),
            "state": state,
            "samples": samples,
            "frames": dict(frames),
            "active_faults": active_faults,
        }
        self._write_message(TOPIC_STATUS, timestamp_ns, encode_message(message))
