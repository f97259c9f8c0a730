"""Helpers for the workbench tests: small synthetic scene folders, a running app on a free
port, and a headless Chromium driven by Playwright (Debian's /usr/bin/chromium, never a
downloaded browser). Imported by ``tests/test_app_*.py``."""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Callable

import pytest

from l2e_studio.app.screenshot import CHROMIUM_ARGS, free_port  # noqa: F401 (free_port: for the tests)

CHROMIUM = Path(os.environ.get("L2E_CHROMIUM", "/usr/bin/chromium"))
ARTIFACTS = Path(__file__).resolve().parents[1] / "test-artifacts" / "app"
VIEWPORT = {"width": 1600, "height": 900}

#: Small scenes: fast to load and to optimise, big enough for a meaningful MI.
SMALL = dict(n_scenes=4, width=320, height=180, points_per_scan=5000, seed=3)


def write_small_scenes(folder: Path, **changes) -> Path:
    """A synthetic scene folder (event/, lidar/, camera.yaml, truth.yaml)."""
    from l2e_studio.synth import SynthConfig, write_dataset

    return write_dataset(folder, SynthConfig(**{**SMALL, **changes}))


def write_event_recordings(folder: Path, duration_s: float = 4.0, share: float = 0.25, seed: int = 5) -> list[Path]:
    """Replace each ``event/*.png`` of a scene folder with a raw recording (``.npz``: x, y, t in
    us, p) whose events over ``duration_s`` add up to ``share`` of the map's counts, plus a
    little uniform noise and a few hot pixels that fire all the time. Returns the recordings."""
    import cv2
    import numpy as np

    rng = np.random.default_rng(seed)
    out = []
    for png in sorted((folder / "event").glob("*.png")):
        counts = np.rint(cv2.imread(str(png), cv2.IMREAD_UNCHANGED).astype(np.float64) * share).astype(np.int64)
        h, w = counts.shape
        ys, xs = np.divmod(np.repeat(np.arange(h * w), counts.ravel()), w)
        n_noise, hot = int(0.05 * h * w * duration_s), rng.integers(0, [w, h], size=(4, 2))
        n_hot = int(400 * duration_s)
        xs = np.concatenate([xs, rng.integers(0, w, n_noise), np.repeat(hot[:, 0], n_hot)])
        ys = np.concatenate([ys, rng.integers(0, h, n_noise), np.repeat(hot[:, 1], n_hot)])
        t = rng.integers(0, int(duration_s * 1e6), xs.size)
        order = np.argsort(t, kind="stable")
        path = png.with_suffix(".npz")
        np.savez(path, x=xs[order].astype(np.uint16), y=ys[order].astype(np.uint16), t=t[order].astype(np.int64),
                 p=rng.integers(0, 2, xs.size).astype(np.uint8))
        png.unlink()
        out.append(path)
    return out


def wait_for(condition: Callable[[], object], timeout: float = 20.0, interval: float = 0.02,
             what: str | Callable[[], str] = "") -> object:
    """Poll ``condition`` until it returns something truthy; fail the test on timeout, saying
    ``what`` was awaited (a callable: called then, to say how things stood)."""
    deadline = time.monotonic() + timeout
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout:.0f} s waiting for {(what() if callable(what) else what) or condition}")
        time.sleep(interval)


def need_chromium() -> None:
    if not CHROMIUM.is_file():
        pytest.skip(f"{CHROMIUM} is absent: the browser tests need Debian's chromium (apt-get install chromium)")
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        pytest.skip("the python playwright package is not installed (pip install -e '.[test]')")


def launch_browser(playwright):
    """Headless Chromium; Playwright gives each launch a fresh temporary profile folder."""
    return playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS, headless=True)


def new_context(browser):
    """A browser context (its own cookies, cache and connections) at the screenshot size.

    Close it before stopping the app: an open context keeps connections that make the
    viser server's shutdown wait for seconds.
    """
    context = browser.new_context(viewport=VIEWPORT)
    context.set_default_timeout(30_000)
    return context


def screenshot(page, name: str) -> Path:
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    path = ARTIFACTS / f"{name}.png"
    page.screenshot(path=str(path))
    return path
