"""The docs site, built once per session as the README says (`python -m sphinx -W -b html
docs ...`: warnings are errors), served over HTTP to a headless Chromium."""

from __future__ import annotations

import functools
import http.server
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.conftest import REPO
from tests.docs.browser import Chromium, find_chromium

DOCS = REPO / "docs"


@pytest.fixture(scope="session")
def site(tmp_path_factory) -> Path:
    """The built site's directory; the build's output is in the failure when it fails."""
    pytest.importorskip("sphinx", reason="the docs extra is not installed: pip install "
                                         "-e '.[docs]'")
    out = tmp_path_factory.mktemp("site")
    done = subprocess.run(
        [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
         "-d", str(out / ".doctrees"), str(DOCS), str(out / "html")],
        capture_output=True, text=True, timeout=1800, cwd=REPO)
    assert done.returncode == 0, f"the docs build failed:\n{done.stdout}\n{done.stderr}"
    return out / "html"


@pytest.fixture(scope="session")
def served(site) -> Iterator[str]:
    """The site on http://127.0.0.1:PORT (as a reader's browser gets it, not file://)."""
    handler = functools.partial(_Quiet, directory=str(site))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, format, *args):
        pass


@pytest.fixture(scope="session")
def chromium() -> Iterator[Chromium]:
    executable = find_chromium()
    if executable is None:
        done = subprocess.run([str(REPO / "deploy" / "install-chromium")], capture_output=True,
                              text=True, timeout=900)
        executable = find_chromium()
        if executable is None:
            pytest.skip(f"no Chromium here ({done.stderr.strip()}): deploy/install-chromium "
                        f"installs it as root on Debian or Ubuntu")
    browser = Chromium(executable)
    yield browser
    browser.close()
