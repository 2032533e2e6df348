"""Every shell block of the tutorials, and the README's five lines, runs as written (issue 44),
in a fresh directory per page with the repository's `deploy/` and `tests/data/` beside it, the
blocks of a page one after the other, as a reader would type them. A block may be marked just
before its fence:

    <!-- doc-test: skip (why) -->                       not run: the reason is printed
    <!-- doc-test: shorten "A" -> "B"; "C" -> "D" -->   run with each A replaced by B (a
                                                        long run made short)

A block that fails fails its page's test with the block, its output and its exit status."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import REPO

TUTORIALS = sorted((REPO / "docs" / "tutorials").glob("*.md"))
BLOCK = re.compile(r"(?:<!-- doc-test: (?P<mark>[^\n]*?) -->\n)?```sh\n(?P<code>.*?)```", re.S)
SHORTEN = re.compile(r'"([^"]+)" -> "([^"]*)"')


def shell_blocks(text: str) -> list[tuple[str, str | None]]:
    """(code to run, or None when skipped; the mark) of every ```sh block of a page."""
    blocks = []
    for match in BLOCK.finditer(text):
        code, mark = match["code"], match["mark"] or ""
        if mark.startswith("skip"):
            assert re.fullmatch(r"skip \(.+\)", mark), f"a skip says why: {mark!r}"
            blocks.append((None, mark))
            continue
        if mark:
            assert mark.startswith("shorten "), f"unknown doc-test mark {mark!r}"
            pairs = SHORTEN.findall(mark)
            assert pairs, f"shorten what? {mark!r}"
            for old, new in pairs:
                assert old in code, f"{old!r} is not in the block it shortens"
                code = code.replace(old, new)
        blocks.append((code, mark))
    return blocks


def run_page(blocks: list[tuple[str | None, str]], work: Path) -> tuple[list[str], str]:
    """Run a page's blocks in ``work``: (the marks of those skipped, the last one's stdout)."""
    for name in ("deploy", "tests"):
        (work / name).mkdir()
    (work / "deploy" / "config").symlink_to(REPO / "deploy" / "config")
    (work / "tests" / "data").symlink_to(REPO / "tests" / "data")
    bin_dir = str(Path(sys.executable).parent)
    env = {**os.environ, "PATH": bin_dir + os.pathsep + os.environ.get("PATH", ""),
           "COLUMNS": "100"}
    env.pop("PYTHONPATH", None)  # the installed package, as a reader has it
    skipped, out = [], ""
    for code, mark in blocks:
        if code is None:
            skipped.append(mark)
            continue
        done = subprocess.run(["bash", "-euo", "pipefail", "-c", code], cwd=work, env=env,
                              capture_output=True, text=True, timeout=1200)
        assert done.returncode == 0, (f"exit {done.returncode}:\n{code}\n--- stdout\n"
                                      f"{done.stdout[-3000:]}\n--- stderr\n{done.stderr[-3000:]}")
        out = done.stdout
    return skipped, out


def test_the_marks_are_read_as_meant():
    text = ('<!-- doc-test: skip (no bus) -->\n```sh\ncanfdi run\n```\n'
            '<!-- doc-test: shorten "--runs 100" -> "--runs 3" -->\n```sh\nx --runs 100\n```\n'
            '```sh\necho plain\n```\n')
    assert shell_blocks(text) == [(None, "skip (no bus)"), ("x --runs 3\n", 'shorten "--runs '
                                  '100" -> "--runs 3"'), ("echo plain\n", "")]
    for bad in ('<!-- doc-test: skip -->\n```sh\nx\n```\n',
                '<!-- doc-test: shorten "--y" -> "--z" -->\n```sh\nx\n```\n',
                '<!-- doc-test: maybe -->\n```sh\nx\n```\n'):
        with pytest.raises(AssertionError):
            shell_blocks(bad)


@pytest.mark.parametrize("page", TUTORIALS, ids=lambda p: p.stem)
def test_every_shell_block_of_a_tutorial_runs(page, tmp_path, capsys):
    blocks = shell_blocks(page.read_text())
    assert [code for code, _ in blocks if code is not None], f"{page.name} has no command"
    if page.stem == "fleet":
        pytest.importorskip("dask.distributed", reason="the fleet extra is not installed")
    skipped, _ = run_page(blocks, tmp_path)
    with capsys.disabled():
        for mark in skipped:
            print(f"\n{page.name}: a block not run: {mark}")


def test_the_readme_five_lines_run(tmp_path):
    text = (REPO / "README.md").read_text()
    section = text.split("<!-- five-lines -->", 1)[1].split("<!-- /five-lines -->", 1)[0]
    blocks = shell_blocks(section)
    assert len(blocks) == 1 and len(blocks[0][0].strip().splitlines()) == 5
    _, diagnosed = run_page(blocks, tmp_path)
    found = diagnosed.split("diagnosed:", 1)[1]
    assert re.search(r"sensor +1 Iq_Measured +onset k=4000", found), diagnosed
    assert re.search(r"sensor +2 Vel_Estimate +onset k=8000", found), diagnosed
