"""A headless Chromium driven over the DevTools protocol (websockets, no browser-driver
package): open a page, wait for its load event, and say what went wrong on it: console
errors, uncaught exceptions, resources that failed to load, images that did not load."""

from __future__ import annotations

import contextlib
import itertools
import json
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from websockets.sync.client import connect


def find_chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


@dataclass
class PageReport:
    url: str
    errors: list[str] = field(default_factory=list)
    broken_images: list[str] = field(default_factory=list)
    images: int = 0
    title: str = ""


class Chromium:
    """One headless browser and one tab; `open(url)` loads a page and reports on it."""

    def __init__(self, executable: str, timeout: float = 30.0) -> None:
        self.timeout = timeout
        self._profile = tempfile.mkdtemp(prefix="canfdi-chromium-")
        self._proc = subprocess.Popen(
            [executable, "--headless=new", "--no-sandbox", "--disable-gpu",
             "--no-first-run", "--remote-debugging-port=0", f"--user-data-dir={self._profile}",
             "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        port_file = Path(self._profile) / "DevToolsActivePort"
        deadline = time.monotonic() + timeout
        while not port_file.exists() or len(port_file.read_text().split()) < 2:
            if time.monotonic() > deadline or self._proc.poll() is not None:
                self.close()
                raise RuntimeError("Chromium did not start (no DevToolsActivePort)")
            time.sleep(0.05)
        port, path = port_file.read_text().split()[:2]
        self._stack = contextlib.ExitStack()
        self._ws = self._stack.enter_context(connect(f"ws://127.0.0.1:{port}{path}",
                                                     max_size=None, open_timeout=timeout))
        self._ids = itertools.count(1)
        self._events: list[dict[str, Any]] = []
        target = self._call("Target.createTarget", {"url": "about:blank"})["targetId"]
        self._session = self._call("Target.attachToTarget",
                                   {"targetId": target, "flatten": True})["sessionId"]
        for domain in ("Page", "Runtime", "Log"):
            self._call(f"{domain}.enable", session=True)

    def _call(self, method: str, params: dict | None = None, session: bool = False) -> dict:
        ident = next(self._ids)
        message: dict[str, Any] = {"id": ident, "method": method, "params": params or {}}
        if session:
            message["sessionId"] = self._session
        self._ws.send(json.dumps(message))
        while True:
            reply = json.loads(self._ws.recv(timeout=self.timeout))
            if reply.get("id") == ident:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply.get("result", {})
            if "method" in reply:
                self._events.append(reply)

    def _wait_for(self, event: str) -> None:
        deadline = time.monotonic() + self.timeout
        while not any(e["method"] == event for e in self._events):
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"no {event} in {self.timeout} s")
            self._events.append(json.loads(self._ws.recv(timeout=left)))

    def open(self, url: str, settle: float = 0.3) -> PageReport:
        self._events.clear()
        self._call("Page.navigate", {"url": url}, session=True)
        self._wait_for("Page.loadEventFired")
        # what a page's scripts do just after load: errors they log count too
        end = time.monotonic() + settle
        while time.monotonic() < end:
            try:
                self._events.append(json.loads(self._ws.recv(timeout=end - time.monotonic())))
            except TimeoutError:
                break
        report = PageReport(url)
        for event in self._events:
            params = event.get("params", {})
            if event["method"] == "Runtime.exceptionThrown":
                details = params.get("exceptionDetails", {})
                report.errors.append("exception: " + str(details.get("exception", {}).get(
                    "description", details.get("text"))))
            elif event["method"] == "Runtime.consoleAPICalled" and params.get("type") == "error":
                report.errors.append("console.error: " + " ".join(
                    str(a.get("value", a.get("description"))) for a in params.get("args", [])))
            elif event["method"] == "Log.entryAdded" and params["entry"]["level"] == "error":
                entry = params["entry"]
                report.errors.append(f"{entry.get('source')}: {entry.get('text')} "
                                     f"{entry.get('url', '')}".strip())
        found = self._call("Runtime.evaluate", {"returnByValue": True, "expression": (
            "({title: document.title, images: document.images.length, broken: "
            "Array.from(document.images).filter(i => !(i.complete && i.naturalWidth > 0))"
            ".map(i => i.currentSrc || i.src)})")}, session=True)["result"]["value"]
        report.title, report.images = found["title"], found["images"]
        report.broken_images = found["broken"]
        return report

    def close(self) -> None:
        try:
            if hasattr(self, "_stack"):
                self._stack.close()
        finally:
            self._proc.kill()
            self._proc.wait(timeout=10)
            shutil.rmtree(self._profile, ignore_errors=True)
