"""`McapLogHandler`: Python logging into a recording's ``/canfdi/log`` topic."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TYPE_CHECKING

from canfdi.io.segmented import LOGGER_NAME

if TYPE_CHECKING:
    from canfdi.io.writer import McapRecorder

__all__ = ["McapLogHandler"]

class McapLogHandler(logging.Handler):
    """A logging handler that records log lines on the recorder's `TOPIC_LOG` (Foxglove's Log
    panel), at the drive's time.

    Parameters
    ----------
    recorder : McapRecorder
        Where the lines go (nothing once it is closed).
    clock : callable
        The drive's time now, integer ns (the time of the last frame the monitor saw).
    level : int
        The least level recorded (default WARNING).

    The recorder's own warnings (a full disk) are not recorded through it: they are about the
    recording itself, and writing them would re-enter the recorder while it fails.
    """

    def __init__(self, recorder: McapRecorder, clock: Callable[[], int],
                 level: int = logging.WARNING) -> None:
        super().__init__(level)
        self.recorder = recorder
        self._clock = clock

    def emit(self, record: logging.LogRecord) -> None:
        if record.name == LOGGER_NAME or self.recorder.closed:
            return
        level = {logging.DEBUG: "debug", logging.INFO: "info", logging.WARNING: "warning",
                 logging.ERROR: "error"}.get(record.levelno,
                                             "fatal" if record.levelno > logging.ERROR else "info")
        try:
            self.recorder.write_log(self._clock(), level, record.getMessage(), record.name,
                                     record.pathname, record.lineno)
        except Exception:  # a log line must never break what logged it
            self.handleError(record)
