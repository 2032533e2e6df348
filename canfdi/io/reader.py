"""Read canfdi's MCAP logs back: messages, metadata, frames, samples and residuals as arrays.

`read_log` streams one file's messages in file order (no summary needed: a file cut short by a
killed writer reads up to its last complete record); `read_metadata` gives the run-level
``"canfdi"`` record (both canfdi.io.logreader's); `read_frames` (`iter_frame_blocks` a block at
a time, `mcap_frame_blocks` replay's read-ahead fast path: canfdi.io.framereader's) gives a
whole log's frames (every rotated segment, canfdi.io.segments). `read_rows` is the one reader
of every row topic (canfdi.io.rowtopics), in their one-row-per-message layout and the older
blocks of rows; `read_samples` and `read_residuals` are its forms for samples and residuals.

Every one of them reads through canfdi.io.scan's `McapFile`, which checks each chunk's CRC,
skips what is damaged and resynchronises after it: a damaged log reads what is left of it,
never raises for the damage, and records what it lost in the canfdi.io.damage `Damage` given
as ``damage=`` (pass one `Damage` to every read of a log, print its lines at the end).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from canfdi.io.blocks import NS_PER_S, Rows, gathered
from canfdi.io.damage import Damage
from canfdi.io.framereader import iter_frame_blocks, mcap_frame_blocks, read_frames
from canfdi.io.logreader import LogReader, log_files, read_log, read_metadata
from canfdi.io.rowtopics import ROW_LAYOUTS, RowLayout
from canfdi.io.schemas import TOPIC_RESIDUALS, TOPIC_SAMPLES

__all__ = [
    "LogReader",
    "ResidualArrays",
    "RowArrays",
    "SampleArrays",
    "iter_frame_blocks",
    "log_drives",
    "mcap_frame_blocks",
    "read_frames",
    "read_log",
    "read_metadata",
    "read_residuals",
    "read_rows",
    "read_samples",
]


# ------------------------------------------------------------------------------------------
# reading rows back
# ------------------------------------------------------------------------------------------


class SampleArrays(NamedTuple):
    """Decoded samples of a log: ``(k, t_ns, gap, U, Z, input_names, output_names)``.

    ``k``, ``t_ns``, ``gap`` are (N,) int64; ``U`` (N, p) and ``Z`` (N, q) float64 with NaN
    where the log holds null; the names are the model's, in column order.
    """

    k: NDArray[np.int64]
    t_ns: NDArray[np.int64]
    gap: NDArray[np.int64]
    U: NDArray[np.float64]
    Z: NDArray[np.float64]
    input_names: list[str]
    output_names: list[str]


class ResidualArrays(NamedTuple):
    """Residuals of a log: ``(k, t_ns, names, R, Rn, stat)``.

    ``k``, ``t_ns`` are (N,) int64; ``R`` (raw), ``Rn`` (normalized), ``stat`` (Page-Hinkley)
    are (N, m) float64 with NaN where the log holds null, columns in ``names`` order.
    """

    k: NDArray[np.int64]
    t_ns: NDArray[np.int64]
    names: list[str]
    R: NDArray[np.float64]
    Rn: NDArray[np.float64]
    stat: NDArray[np.float64]


def _same_names(found: tuple[list[str], ...], names: tuple[list[str], ...] | None, topic: str,
                path: str | Path) -> tuple[list[str], ...]:
    """``found``, checked equal to the ``names`` read before (None: none yet)."""
    if names is not None and found != names:
        def shown(lists: tuple[list[str], ...]) -> Any:
            return lists[0] if len(lists) == 1 else lists
        raise ValueError(f"{topic} of {path} changes names: {shown(names)} then {shown(found)}")
    return found


def log_drives(path: str | Path, *, segments: bool = True,
               damage: Damage | None = None) -> list[str]:
    """The drives whose samples a log holds, in order of appearance ([] for a log of one
    unnamed drive: logs written before drives had names); damage recorded in ``damage``."""
    found: list[str] = []
    for segment in log_files(path, segments):
        for _, _, msg in read_log(segment, [TOPIC_SAMPLES], damage):
            drive = msg.get("drive")
            if drive is not None and drive not in found:
                found.append(drive)
    return found


def _wanted(msg: Mapping[str, Any], drive: str | None, first: list) -> bool:
    """Whether a block belongs to ``drive`` (None: the first drive the log shows)."""
    found = msg.get("drive")
    if drive is not None:
        return found == drive
    if not first:
        first.append(found)
    return found == first[0]


@dataclass(frozen=True)
class RowArrays:
    """The rows of a row topic (canfdi.io.rowtopics) as arrays.

    Attributes
    ----------
    t_ns : (N,) int64
        The rows' times.
    columns : dict of str to ndarray
        Every integer field, (N,) int64, and every group, (N, width) float64 with NaN where
        the log holds null, columns in the order of its name list.
    names : tuple of list of str
        The layout's name lists (empty lists when the log holds no row).

    Examples
    --------
    >>> rows = RowArrays(np.array([5]), {"k": np.array([0]), "x": np.array([[1.5]])}, (["a"],))
    >>> rows.columns["x"][0, rows.names[0].index("a")]
    np.float64(1.5)
    """

    t_ns: NDArray[np.int64]
    columns: dict[str, np.ndarray]
    names: tuple[list[str], ...]


def _row_names(layout: RowLayout, msg: Mapping[str, Any]) -> tuple[list[str], ...]:
    """The name lists of one row message: each list's first group's keys."""
    return tuple(list(msg[next(key for key, which in layout.groups if which == i)])
                 for i in range(len(layout.names)))


def _row_values(layout: RowLayout, msg: Mapping[str, Any], log_time: int,
                names: tuple[list[str], ...]) -> tuple[Any, ...]:
    """One row message's values, a value per buffered column."""
    ints = [msg.get(key, layout.defaults[key]) if key in layout.defaults else msg[key]
            for key in layout.ints]
    groups = [[msg[key][name] for name in names[which]] for key, which in layout.groups]
    # The row's own time: its log time may have been held at the one before it (a clock that
    # stepped back, two drives' rows interleaved; canfdi.io.writer keeps log times in order).
    stamp = msg.get("timestamp")
    if isinstance(stamp, Mapping):
        log_time = int(stamp["sec"]) * NS_PER_S + int(stamp["nsec"])
    elif "t_ns" in msg:  # a ROS 2 row (canfdi.io.cdr)
        log_time = int(msg["t_ns"])
    return (log_time, *ints, *groups)


def read_rows(path: str | Path, topic: str, *, segments: bool = True,
              drive: str | None = None, damage: Damage | None = None) -> RowArrays:
    """Every row of a row topic (canfdi.io.rowtopics) in a log, as arrays.

    Reads every segment in order, tolerating a truncated end as `read_log` does, and the
    topic's older layout of blocks of rows (`RowLayout.legacy`).

    Parameters
    ----------
    path : str or Path
        The log's name (its first segment).
    topic : str
        A registered row topic.
    segments : bool
        Also read the rotated segments that follow ``path`` (`log_segments`); False reads
        ``path`` alone.
    drive : str, optional
        Whose rows (a log of several drives, `log_drives`); default the first drive's.
    damage : Damage, optional
        Where what damaged segments lost is recorded (the rows in them are not read).

    Returns
    -------
    RowArrays
        Empty arrays (and empty name lists) when the log holds no row.

    Raises
    ------
    FileNotFoundError
        If no segment of the log exists.
    ValueError
        For a topic that is not a row topic, a block of an unknown layout, or names that
        change within the log.
    """
    layout = ROW_LAYOUTS.get(topic)
    if layout is None:
        raise ValueError(f"{topic} is not a row topic (canfdi.io.rowtopics.ROW_LAYOUTS)")
    rows = Rows(layout.kinds)
    names: tuple[list[str], ...] | None = None
    first: list = []
    for segment in log_files(path, segments):
        for _, log_time, msg in read_log(segment, [topic], damage):
            if not _wanted(msg, drive, first):
                continue
            if "count" in msg and layout.legacy is not None:
                found, columns = layout.legacy(msg)
                names = _same_names(found, names, topic, path)
                rows.add(columns)
            else:
                found = _row_names(layout, msg)
                names = _same_names(found, names, topic, path)
                rows.append(_row_values(layout, msg, log_time, found))
    names = names if names is not None else tuple([] for _ in layout.names)
    widths = layout.widths(names)
    arrays = gathered(rows, widths)
    n = len(arrays[0])
    i = 1 + len(layout.ints)
    columns = dict(zip(layout.ints, arrays[1:i], strict=True))
    columns.update((key, values.reshape(n, width)) for (key, _), values, width in
                   zip(layout.groups, arrays[i:], widths, strict=True))
    return RowArrays(arrays[0], columns, names)


def read_samples(path: str | Path, *, segments: bool = True, drive: str | None = None,
                 damage: Damage | None = None) -> SampleArrays:
    """Every decoded sample of a log (``/canfdi/samples``), as arrays (`read_rows`).

    Parameters
    ----------
    path : str or Path
        The log's name (its first segment).
    segments : bool
        Also read the rotated segments that follow ``path`` (`log_segments`); False reads
        ``path`` alone.
    drive : str, optional
        Whose samples (a log of several drives, `log_drives`); default the first drive's.
    damage : Damage, optional
        Where what damaged segments lost is recorded (the samples in them are not read).

    Returns
    -------
    SampleArrays
        ``(k, t_ns, gap, U, Z, input_names, output_names)``; empty arrays (and no names) when
        the log holds no sample.

    Raises
    ------
    FileNotFoundError
        If no segment of the log exists.
    ValueError
        For a block of an unknown layout, or names that change within the log.
    """
    rows = read_rows(path, TOPIC_SAMPLES, segments=segments, drive=drive, damage=damage)
    c = rows.columns
    return SampleArrays(c["k"], rows.t_ns, c["gap"], c["u"], c["z"], *rows.names)


def read_residuals(path: str | Path, *, segments: bool = True, drive: str | None = None,
                   damage: Damage | None = None) -> ResidualArrays:
    """Every residual row of a log (``/canfdi/residuals``), as arrays (`read_rows`).
    (``/canfdi/residuals_plot`` of older logs is not read: it only repeats some of these
    rows.)

    Parameters
    ----------
    path : str or Path
        The log's name (its first segment).
    segments : bool
        Also read the rotated segments that follow ``path`` (`log_segments`); False reads
        ``path`` alone.
    drive : str, optional
        Whose residuals (a log of several drives); default the first drive's.
    damage : Damage, optional
        Where what damaged segments lost is recorded (the rows in them are not read).

    Returns
    -------
    ResidualArrays
        ``(k, t_ns, names, R, Rn, stat)``; empty arrays (and no names) when the log holds no
        residuals.

    Raises
    ------
    FileNotFoundError
        If no segment of the log exists.
    ValueError
        For a block of an unknown layout, or names that change within the log.
    """
    rows = read_rows(path, TOPIC_RESIDUALS, segments=segments, drive=drive, damage=damage)
    c = rows.columns
    (names,) = rows.names
    return ResidualArrays(c["k"], rows.t_ns, names, c["r"], c["normalized"], c["statistic"])


