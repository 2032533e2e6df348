"""The docs site (issue 44): it builds with warnings as errors (so every internal link and
page resolves), every page and the fleet's HTML report load in a headless Chromium without a
console error and with all their images, the README is one screen whose links resolve, and
its figure is the one the build draws from a real run."""

from __future__ import annotations

import re
from pathlib import Path
from urllib.parse import unquote, urlparse

import numpy as np
import pytest

from tests.conftest import REPO
from tests.docs.conftest import DOCS

README = REPO / "README.md"
LINK = re.compile(r"\]\(([^)\s]+)\)")


def _pages(site: Path) -> list[Path]:
    """The site's own pages (not the fleet report it carries: a test of its own)."""
    return sorted(p for p in site.rglob("*.html")
                  if not {"_static", "fleet-report"} & set(p.relative_to(site).parts))


def test_every_page_of_the_tree_is_in_the_site(site):
    pages = {p.relative_to(site).with_suffix("").as_posix() for p in _pages(site)}
    sources = {p.relative_to(DOCS).with_suffix("").as_posix() for p in DOCS.rglob("*.md")
               if not {"_build", "_generated", "figures"} & set(p.relative_to(DOCS).parts)}
    assert sources <= pages, sorted(sources - pages)
    for part in ("reference/cli", "reference/config", "reference/topics", "reference/api"):
        text = (site / f"{part}.html").read_text()
        assert len(text) > 20_000, f"{part}: generated content missing"
    assert "canfdi identify" in (site / "reference/cli.html").read_text()
    assert "detection.drift: expected a number" in (site / "reference/config.html").read_text()
    assert "/canfdi/residuals" in (site / "reference/topics.html").read_text()


def test_every_local_link_and_image_of_the_site_resolves(site):
    missing = []
    for page in _pages(site):
        for target in re.findall(r'(?:href|src)="([^"#?]+)', page.read_text()):
            if urlparse(target).scheme or target.startswith(("//", "mailto:")):
                continue
            if not (page.parent / unquote(target)).exists():
                missing.append(f"{page.relative_to(site)} -> {target}")
    assert missing == []


def test_every_page_loads_in_chromium_without_an_error(site, served, chromium):
    pages = _pages(site)
    assert len(pages) > 30
    images = 0
    for page in pages:
        report = chromium.open(f"{served}/{page.relative_to(site).as_posix()}")
        assert report.errors == [], report
        assert report.broken_images == [], report
        assert report.title, report
        images += report.images
    assert images >= 6  # the build's figures, each on its page


def test_the_fleet_report_loads_in_chromium(site, served, chromium):
    reports = sorted((site / "fleet-report").glob("*.html"))
    assert [p.name for p in reports] == ["index.html", "press-1.html", "press-2.html"]
    for page in reports:
        report = chromium.open(f"{served}/fleet-report/{page.name}")
        assert report.errors == [] and report.broken_images == [], report
        assert report.images >= 1, report
    index = (site / "fleet-report" / "index.html").read_text()
    assert "press-1" in index and "trend" in index


def test_the_readme_is_one_screen_and_its_links_resolve():
    text = README.read_text()
    assert len(text.splitlines()) <= 200
    for marker in ("main-command", "test-command", "five-lines"):
        assert text.count(f"<!-- {marker} -->") == 1 and text.count(f"<!-- /{marker} -->") == 1
    for target in LINK.findall(text):
        if urlparse(target).scheme:
            continue
        assert (REPO / target.split("#")[0]).exists(), target


def test_the_readme_figure_is_the_one_the_build_draws(site):
    """The README's copy against the figure the build drew from its own demo run: the same
    size, and pixels that differ little (a font's rendering may; a moved diagnosis, threshold
    or curve does not)."""
    matplotlib = pytest.importorskip("matplotlib.image")
    fresh = matplotlib.imread(DOCS / "_generated" / "figures" / "diagnosed-run.png")
    kept = matplotlib.imread(DOCS / "figures" / "diagnosed-run.png")
    assert kept.shape == fresh.shape, "docs/figures/diagnosed-run.png is stale: copy it from " \
                                      "docs/_generated/figures/ after a docs build"
    differ = np.abs(kept[..., :3] - fresh[..., :3]).max(axis=-1) > 0.2
    assert differ.mean() < 0.002, (
        f"{differ.mean():.2%} of docs/figures/diagnosed-run.png differs from the build's: "
        "copy it from docs/_generated/figures/ after a docs build")
