"""The log formats canfdi reads and writes, by file name: the one registry.

A `LogFormat` says what a file of its suffix holds and how to read its frames (FrameBlocks,
canfdi.bus.frames), its run-level metadata (and so the injected faults of a demo) where it has
any, and how to write frames into one. `format_of` maps a file name to its format (the longest
registered suffix that ends the name, case-insensitive); an unknown suffix is a
`LogFormatError` naming the known ones. Every reader of logs (replay, identify, bench, report,
export) goes through here; `register` adds a format (the plug-in point of DESIGN.md).

Registered:

* ``.mcap``: canfdi's own log (canfdi.io.reader and .writer): frames with the statuses the
  monitor gave them, metadata, and the samples, residuals and events of a run (`records`).
* Every format python-can reads and writes (canfdi.io.pycan): ``.asc``, ``.blf``, ``.log``
  (candump -L), ``.trc``, ``.csv``, ``.db`` (SQLite), ``.mf4`` (needs the asammdf package:
  ``pip install 'canfdi[mf4]'``), and the gzip-compressed text logs ``.asc.gz``, ``.log.gz``,
  ``.trc.gz``, ``.csv.gz``; ``.blf.gz`` is read only (python-can's BLF writer cannot write
  into a gzip stream).

Reading a log that is not what its suffix says (random bytes, a truncated binary header) raises
`LogReadError` with one line naming the file and the format, never the parser's own exception;
a missing file raises FileNotFoundError.
"""

from __future__ import annotations

import errno
import gzip
import importlib.util
import json
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

from canfdi.bus.frames import FrameBlock
from canfdi.io.damage import Damage
from canfdi.io.pycan import Written
from canfdi.io.segments import log_segments

__all__ = [
    "LogFormat",
    "LogFormatError",
    "LogReadError",
    "Written",
    "format_named",
    "format_of",
    "formats",
    "register",
]


class LogFormatError(ValueError):
    """A file name of no registered format, or a format that cannot do what is asked (write,
    or read without a package it needs)."""


class LogReadError(ValueError):
    """A log that cannot be read as the format its name says (damaged, or another format)."""


ReadFn = Callable[[Path, int, bool], Iterator[FrameBlock]]
WriteFn = Callable[[Path, Iterable[FrameBlock]], Written]


@dataclass(frozen=True)
class LogFormat:
    """One log format: its suffix, what it keeps, its reader and writer.

    Attributes
    ----------
    name : str
        Short name (``"mcap"``, ``"asc"``, ``"asc.gz"``...): ``canfdi export --format``'s.
    suffix : str
        The file-name ending that says the format, lower case (``".asc.gz"``).
    description : str
        What it is, for people (``"Vector ASCII (CANalyzer, SavvyCAN)"``).
    reader : callable
        ``reader(path, frames_per_block, received) -> iterator of FrameBlock`` (and a fourth
        argument, a `Damage`, when `reports_damage`).
    writer : callable or None
        ``writer(path, blocks) -> Written``; None for a format read only.
    metadata_reader : callable or None
        ``metadata_reader(path) -> dict of str to str``: the run-level record (config, design,
        truth); None for a format with none.
    records : bool
        The log holds a monitor run's samples, residuals and events (canfdi.io.reader reads
        them): what ``canfdi report`` needs.
    directions : bool
        The format keeps which frames were sent and which received.
    absolute_time : bool
        Timestamps come back as written (ns since the epoch); False: from the log's start.
    resolution_ns : int
        Timestamp resolution of the format, as python-can writes it.
    holds : frozenset of str
        Frame kinds it can write besides classic data frames: ``"remote"``, ``"error"``,
        ``"fd"`` (CAN FD frames, payloads up to 64 bytes); the writer leaves out the others.
    segments : bool
        The log may go on in rotated segments (``<stem>-0001<suffix>``..., canfdi.io.segments)
        that its reader reads too.
    reports_damage : bool
        The reader skips damaged parts of a log and records them in a canfdi.io.damage
        `Damage` it takes as a fourth argument (canfdi's MCAP: CRC-checked chunks).
    requires : str or None
        A module that must be importable to use the format (``"asammdf"``), and
    extra : str or None
        the pip extra of canfdi that installs it.
    """

    name: str
    suffix: str
    description: str
    reader: ReadFn
    writer: WriteFn | None = None
    metadata_reader: Callable[[Path], dict[str, str]] | None = None
    records: bool = False
    directions: bool = False
    absolute_time: bool = True
    resolution_ns: int = 1000
    holds: frozenset[str] = field(default_factory=lambda: frozenset({"remote", "error", "fd"}))
    segments: bool = False
    reports_damage: bool = False
    requires: str | None = None
    extra: str | None = None

    @property
    def writable(self) -> bool:
        """A writer exists."""
        return self.writer is not None

    def missing(self) -> str | None:
        """What must be installed to use the format, as a sentence; None when nothing is."""
        if self.requires is None or importlib.util.find_spec(self.requires) is not None:
            return None
        how = f"'canfdi[{self.extra}]'" if self.extra else self.requires
        how = f"pip install {how}"
        return f"{self.suffix} logs need the {self.requires} package ({how})"

    def check(self, write: bool = False) -> None:
        """Raise LogFormatError unless the format can be read (or ``write``: written) here."""
        why = self.missing()
        if why is not None:
            raise LogFormatError(why)
        if write and self.writer is None:
            names = ", ".join(f.name for f in formats() if f.writable)
            raise LogFormatError(f"canfdi cannot write {self.suffix} logs (it writes {names})")

    def frame_blocks(self, path: str | Path, frames_per_block: int = 65536, *,
                     received: bool = True, damage: Damage | None = None
                     ) -> Iterator[FrameBlock]:
        """The frames of a log of this format, in blocks of about ``frames_per_block``.

        Parameters
        ----------
        path : str or Path
            The log (for MCAP, its first segment: the rotated ones follow).
        frames_per_block : int
            Frames per block, about.
        received : bool
            Only the frames a monitor on that bus received: an MCAP's own transmissions
            (status ``"sent"``) are left out. A python-can log's Tx frames stay: the node that
            logged them sent them on the bus, where a monitor hears them. False: every frame.
        damage : Damage, optional
            Where a format that `reports_damage` records what a damaged log lost (the rest is
            read); complete once the iteration ends.

        Yields
        ------
        FrameBlock
            With a status column: the monitor's for MCAP, ``"rx"`` / ``"tx"`` otherwise.

        Raises
        ------
        LogFormatError
            A package the format needs is missing.
        FileNotFoundError
            No such log.
        LogReadError
            (while iterating) the file is not a readable log of this format.
        """
        self.check()
        path = Path(path)
        if not path.exists() and not (self.segments and log_segments(path)):
            raise FileNotFoundError(errno.ENOENT, "no such log", str(path))
        if self.reports_damage and damage is not None:
            blocks = self.reader(path, frames_per_block, received, damage)  # type: ignore
        else:
            blocks = self.reader(path, frames_per_block, received)
        return _guarded(self, path, blocks)

    def write_frames(self, path: str | Path, blocks: Iterable[FrameBlock]) -> Written:
        """Write frames into a new log of this format (an existing file is replaced).

        Parameters
        ----------
        path : str or Path
            The log to write.
        blocks : iterable of FrameBlock
            The frames in order; their statuses say directions (``"sent"`` and ``"tx"`` are
            transmissions) and, for MCAP, are recorded as they are.

        Returns
        -------
        Written
            ``(frames, skipped)``: skipped frames are of a kind the format cannot hold.

        Raises
        ------
        LogFormatError
            The format cannot be written (here).
        OSError
            The file cannot be written.
        """
        self.check(write=True)
        assert self.writer is not None
        return self.writer(Path(path), blocks)

    def metadata(self, path: str | Path) -> dict[str, str]:
        """The log's run-level metadata (``config_yaml``, ``truth_json``...); empty for a
        format without any. Raises LogReadError for a damaged log of a format that has it."""
        if self.metadata_reader is None:
            return {}
        try:
            return self.metadata_reader(Path(path))
        except OSError:
            raise
        except Exception as exc:
            raise LogReadError(_read_error(self, Path(path), exc)) from None

    def truth(self, path: str | Path) -> list[dict] | None:
        """The faults injected into the run the log recorded (a demo's), or None when the log
        says nothing about them (or cannot be read)."""
        try:
            meta = self.metadata(path)
            return json.loads(meta["truth_json"]) if "truth_json" in meta else None
        except (OSError, ValueError):
            return None


def _read_error(fmt: LogFormat, path: Path, exc: BaseException) -> str:
    """One line: the file, its format and what the parser said (its first line)."""
    what = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    what = what.removeprefix(f"{path}: ")
    return f"{path}: not a readable {fmt.suffix} log ({what})"


def _guarded(fmt: LogFormat, path: Path, blocks: Iterator[FrameBlock]) -> Iterator[FrameBlock]:
    """``blocks``, with any parser error turned into one LogReadError."""
    try:
        yield from blocks
    except gzip.BadGzipFile as exc:
        raise LogReadError(_read_error(fmt, path, exc)) from None
    except (OSError, LogReadError, LogFormatError):
        raise
    except Exception as exc:  # python-can's parsers raise anything for a damaged file
        raise LogReadError(_read_error(fmt, path, exc)) from None


# ------------------------------------------------------------------------------------------
# the registry
# ------------------------------------------------------------------------------------------

_FORMATS: dict[str, LogFormat] = {}


def register(fmt: LogFormat) -> None:
    """Add a format (or replace the one of the same name)."""
    if not fmt.suffix.startswith(".") or fmt.suffix != fmt.suffix.lower():
        raise ValueError(f"a format's suffix is lower case and starts with '.': {fmt.suffix!r}")
    _FORMATS[fmt.name] = fmt


def formats() -> list[LogFormat]:
    """Every registered format, in registration order."""
    return list(_FORMATS.values())


def format_named(name: str) -> LogFormat:
    """The format of a name (``"asc"``, ``"asc.gz"``...); LogFormatError listing the names."""
    try:
        return _FORMATS[name.lower()]
    except KeyError:
        raise LogFormatError(f"unknown log format {name!r} (known: "
                             f"{', '.join(_FORMATS)})") from None


def format_of(path: str | Path) -> LogFormat:
    """The format of a file, by the longest registered suffix that ends its name.

    Raises
    ------
    LogFormatError
        No registered suffix ends the name; the message lists the known suffixes.
    """
    name = Path(path).name.lower()
    found = [f for f in _FORMATS.values() if name.endswith(f.suffix) and name != f.suffix]
    if not found:
        known = " ".join(f.suffix for f in _FORMATS.values())
        raise LogFormatError(f"{Path(path).name}: not a log format canfdi knows by its suffix "
                             f"(known: {known})")
    return max(found, key=lambda f: len(f.suffix))


# ------------------------------------------------------------------------------------------
# the formats
# ------------------------------------------------------------------------------------------


def _mcap_read(path: Path, frames_per_block: int, received: bool,
               damage: Damage | None = None) -> Iterator[FrameBlock]:
    from canfdi.io.reader import mcap_frame_blocks

    return mcap_frame_blocks(path, frames_per_block, received=received, damage=damage)


def _mcap_write(path: Path, blocks: Iterable[FrameBlock]) -> Written:
    from canfdi.io.pycan import RX
    from canfdi.io.writer import McapRecorder

    count = 0
    with McapRecorder(path) as recorder:
        for block in blocks:
            recorder.write_frames(block, RX if block.status is None else None)
            count += block.size
    if recorder.last_error is not None:
        raise recorder.last_error
    return Written(count, 0)


def _mcap_metadata(path: Path) -> dict[str, str]:
    from canfdi.io.reader import read_metadata

    return read_metadata(path)  # NotMcap for a file that is not MCAP


register(LogFormat(
    "mcap", ".mcap", "canfdi MCAP", _mcap_read, _mcap_write, _mcap_metadata, records=True,
    directions=True, resolution_ns=1, segments=True, reports_damage=True))


def _python_can(name: str, description: str, *, compressed: bool = False, write: bool = True,
                directions: bool = True, absolute_time: bool = True, resolution_ns: int = 1000,
                holds: Iterable[str] = ("remote", "error", "fd"), requires: str | None = None,
                extra: str | None = None) -> LogFormat:
    from canfdi.io.pycan import read_blocks, write_blocks

    inner = "." + name.removesuffix(".gz")
    held = frozenset(holds)

    def read(path: Path, frames_per_block: int, received: bool, damage: Damage | None = None
             ) -> Iterator[FrameBlock]:
        return read_blocks(path, inner, compressed, frames_per_block, damage)

    def writer(path: Path, blocks: Iterable[FrameBlock]) -> Written:
        return write_blocks(path, inner, blocks, compressed, held)

    return LogFormat(name, "." + name, description, read, writer if write else None,
                     directions=directions, absolute_time=absolute_time,
                     resolution_ns=resolution_ns, holds=held, requires=requires, extra=extra,
                     reports_damage=name == "blf")


_ASC = "Vector ASCII (CANalyzer, CANoe, SavvyCAN)"
_BLF = "Vector binary logging format (CANalyzer, CANoe, SavvyCAN)"
_LOG = "candump -L text (can-utils canplayer, SavvyCAN)"
_TRC = "PEAK trace (PCAN-View)"
_CSV = "python-can CSV (timestamp, arbitration_id, extended, remote, error, dlc, data)"
for _format in (
    # ASC: the header holds the measurement start, but python-can reads times relative to it.
    _python_can("asc", _ASC, absolute_time=False),
    _python_can("blf", _BLF),
    _python_can("log", _LOG),
    _python_can("trc", _TRC, holds=()),  # python-can's TRC writer: data frames only
    # CSV and SQLite keep a CAN FD payload whole but not the FD flag.
    _python_can("csv", _CSV, directions=False),
    _python_can("db", "python-can SQLite", directions=False),
    _python_can("mf4", "ASAM MDF 4 (asammdf, CANape, Vector)", requires="asammdf",
                extra="mf4"),
    _python_can("asc.gz", "gzip-compressed " + _ASC, compressed=True, absolute_time=False),
    _python_can("blf.gz", "gzip-compressed " + _BLF, compressed=True, write=False),
    _python_can("log.gz", "gzip-compressed " + _LOG, compressed=True),
    _python_can("trc.gz", "gzip-compressed " + _TRC, compressed=True, holds=()),
    _python_can("csv.gz", "gzip-compressed " + _CSV, compressed=True, directions=False),
):
    register(_format)
del _format
