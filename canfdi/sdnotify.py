"""systemd's notify protocol (sd_notify) without a dependency: READY=1, WATCHDOG=1, STOPPING=1.

Under a unit with Type=notify, systemd passes NOTIFY_SOCKET (a unix datagram socket, possibly
abstract: a leading '@') and, with WatchdogSec=, WATCHDOG_USEC. Outside systemd both are absent
and every call here does nothing.
"""

from __future__ import annotations

import os
import socket
import time

__all__ = ["Notifier"]


class Notifier:
    """Sends state strings to systemd; pings the watchdog at half its interval at most."""

    def __init__(self, environ: dict[str, str] | None = None) -> None:
        env = os.environ if environ is None else environ
        address = env.get("NOTIFY_SOCKET", "")
        if address.startswith("@"):
            address = "\0" + address[1:]
        self.address = address or None
        usec = env.get("WATCHDOG_USEC", "")
        self.watchdog_interval = int(usec) / 2e6 if usec.isdigit() and int(usec) > 0 else None
        self._last_ping = 0.0

    @property
    def active(self) -> bool:
        return self.address is not None

    def notify(self, state: str) -> bool:
        """Send one state string; False when not under systemd or the send failed."""
        if self.address is None:
            return False
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
                sock.connect(self.address)
                sock.sendall(state.encode())
            return True
        except OSError:
            return False

    def ready(self, status: str = "") -> None:
        self.notify("READY=1" + (f"\nSTATUS={status}" if status else ""))

    def status(self, text: str) -> None:
        """STATUS=: the one line `systemctl status` shows."""
        self.notify(f"STATUS={text}")

    def stopping(self) -> None:
        self.notify("STOPPING=1")

    def watchdog(self) -> None:
        """Ping the watchdog if half its interval has passed (called from the event loop, so
        a stalled loop stops the pings and systemd restarts the service)."""
        if self.watchdog_interval is None:
            return
        now = time.monotonic()
        if now - self._last_ping >= self.watchdog_interval:
            self._last_ping = now
            self.notify("WATCHDOG=1")
