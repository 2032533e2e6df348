"""The directory where `canfdi run` keeps the results canfdi.core.memo remembers.

One small file per result, named by the digest of its inputs, written atomically (a temporary
file renamed), so that a daemon killed mid-write leaves no half entry. The directory is
``$CANFDI_CACHE_DIR``, else systemd's ``$CACHE_DIRECTORY`` (the units' ``CacheDirectory=``),
else ``$XDG_CACHE_HOME/canfdi``, else ``~/.cache/canfdi``. A store that cannot be read or
written is no error: the result is computed, as without one. Entries are bounded by the
designs a machine has run: one per design, some hundred bytes each.
"""

from __future__ import annotations

import logging
import os
import re
import tempfile
from pathlib import Path

__all__ = ["DirectoryStore", "cache_directory"]

log = logging.getLogger("canfdi.io.memostore")

MAX_ENTRY_BYTES = 1 << 20
"""A file larger than this is not one of ours: ignored, never read whole."""
_KEY = re.compile(r"[0-9a-f]{64}")


def cache_directory(environ: dict[str, str] | None = None) -> Path | None:
    """Where the store lives (see the module's docstring), or None without any home."""
    env = os.environ if environ is None else environ
    if env.get("CANFDI_CACHE_DIR"):
        return Path(env["CANFDI_CACHE_DIR"])
    if env.get("CACHE_DIRECTORY"):  # systemd: several are separated by ':'
        return Path(env["CACHE_DIRECTORY"].split(":")[0])
    if env.get("XDG_CACHE_HOME"):
        return Path(env["XDG_CACHE_HOME"]) / "canfdi"
    home = env.get("HOME")
    return Path(home) / ".cache" / "canfdi" if home else None


class DirectoryStore:
    """canfdi.core.memo.Store over one directory (created when first written)."""

    def __init__(self, directory: Path) -> None:
        self.directory = Path(directory)
        self._warned = False

    def _path(self, key: str) -> Path | None:
        return self.directory / f"{key}.json" if _KEY.fullmatch(key) else None

    def get(self, key: str) -> str | None:
        path = self._path(key)
        if path is None:
            return None
        try:
            with open(path, "rb") as f:
                data = f.read(MAX_ENTRY_BYTES + 1)
        except OSError:
            return None
        if len(data) > MAX_ENTRY_BYTES:
            return None
        return data.decode("utf-8", errors="replace")

    def put(self, key: str, text: str) -> None:
        path = self._path(key)
        if path is None:
            return
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=self.directory, prefix=".", suffix=".tmp")
            try:
                with os.fdopen(fd, "w") as f:
                    f.write(text)
                os.replace(tmp, path)
            except BaseException:
                os.unlink(tmp)
                raise
        except OSError as exc:
            if not self._warned:  # once: the daemon works the same, only starts slower
                self._warned = True
                log.info("cannot keep designs in %s (%s): each start computes them",
                         self.directory, exc)
