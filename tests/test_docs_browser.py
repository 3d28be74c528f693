"""The docs open in a real browser: headless Chromium renders the front page and an API page (a screenshot that is not
blank, and the page's text in the DOM it built).

Chromium is not a Python package: CI's integration stage (``.ci/integration``) installs Debian's ``chromium`` and sets
``DOCS_BROWSER_REQUIRED=1``, where a missing browser fails this test; elsewhere it is skipped where no Chromium is
found (``chromium``, ``chromium-browser``, ``google-chrome`` on ``PATH``, or ``$CHROMIUM``). The link check, which
needs no browser, is in ``tests/test_docs.py``.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pytest
from docs_support import build_docs, session_folder

BROWSER_SECONDS = 120
PAGES = {
    "front page": ("index.html", "Getting started"),
    "API page": ("api/generated/sb3_dcqn.dcqn.html", "td_target"),
}


def chromium() -> str | None:
    for name in (os.environ.get("CHROMIUM"), "chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name) if name else None
        if found:
            return found
    return None


@pytest.fixture(scope="module")
def browser() -> str:
    found = chromium()
    if found is None:
        if os.environ.get("DOCS_BROWSER_REQUIRED") == "1":
            pytest.fail("no Chromium found (chromium, chromium-browser, google-chrome, $CHROMIUM): install it")
        pytest.skip("no Chromium found (CI's integration stage installs Debian's chromium)")
    return found


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_docs(session_folder(tmp_path_factory.getbasetemp()))


def headless(browser: str, *arguments: str) -> subprocess.CompletedProcess[str]:
    """Run headless Chromium with a profile of its own (removed after), no sandbox (CI runs as root), no network."""
    with tempfile.TemporaryDirectory() as profile:
        command = [
            browser, "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--no-first-run",
            f"--user-data-dir={profile}", "--proxy-server=127.0.0.1:9", "--window-size=1280,900", *arguments,
        ]  # fmt: skip
        return subprocess.run(command, capture_output=True, text=True, timeout=BROWSER_SECONDS, check=False)


@pytest.mark.parametrize("which", list(PAGES))
def test_a_page_renders_in_headless_chromium(which: str, browser: str, site: Path, tmp_path: Path) -> None:
    page, text = PAGES[which]
    url = (site / page).resolve().as_uri()
    shot = tmp_path / "page.png"
    result = headless(browser, f"--screenshot={shot}", url)
    assert shot.is_file(), f"no screenshot of {page}: {result.stderr[-2000:]}"
    image = cv2.imread(str(shot))
    assert image is not None and image.shape[0] >= 600 and image.shape[1] >= 1000, f"{page}: {image is None}"
    # Not blank: a page of text and a sidebar has many pixels off its background, and more than a couple of colours
    background = np.median(image.reshape(-1, 3), axis=0)
    drawn = np.abs(image.astype(int) - background).sum(axis=2) > 60
    assert drawn.mean() > 0.01, f"{page} looks blank ({drawn.mean():.4f} of its pixels drawn)"
    assert len(np.unique(image.reshape(-1, 3) // 32, axis=0)) > 4, f"{page} has hardly any colours"
    dom = headless(browser, "--dump-dom", url).stdout
    assert text in dom and "sb3-dcqn" in dom, f"{page}: the rendered DOM lacks {text!r}"
