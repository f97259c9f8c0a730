"""Shared fixtures: small synthetic scene sets with a known extrinsic, built once per session."""

from __future__ import annotations

import ctypes
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from l2e_studio.scenes import Scene
from l2e_studio.synth import SynthConfig, config_with, make_rig, make_scene, write_dataset

SMALL = config_with(SynthConfig(), n_scenes=4, width=640, height=360, points_per_scan=20_000, seed=11)
#: the real recordings beside the project (``$L2E_REALDATA`` points elsewhere, e.g. from a git worktree)
REALDATA = Path(os.environ.get("L2E_REALDATA") or Path(__file__).resolve().parents[2] / "shared" / "realdata")


def _browsers_never_outrank_the_app() -> None:
    """Chromium run as root raises its GPU and compositor threads to nice -8. The test browsers
    share this machine's cores with the app they test (a user's browser runs on their laptop),
    and their software-rendered WebGL at that priority starves the app's threads. Dropping
    CAP_SYS_NICE from this process's bounding set keeps every program the tests start
    (Playwright's driver, chromium, the CLI) at the priority they were given; without the
    capability (not root) there is nothing to drop and the call fails harmlessly."""
    if sys.platform.startswith("linux"):
        PR_CAPBSET_DROP, CAP_SYS_NICE = 24, 23
        ctypes.CDLL(None, use_errno=True).prctl(PR_CAPBSET_DROP, CAP_SYS_NICE, 0, 0, 0)


_browsers_never_outrank_the_app()


@pytest.fixture(scope="session")
def small_synth():
    """(scenes, camera, truth) of four small synthetic scenes."""
    camera, truth, _ = make_rig(SMALL)
    scenes = []
    for i in range(SMALL.n_scenes):
        points, intensity, emap = make_scene(SMALL, i, truth, camera)
        scenes.append(Scene(f"scene_{i:03d}", points, intensity, emap.astype(np.float32)))
    return scenes, camera, truth


@pytest.fixture(scope="session")
def small_synth_dir(tmp_path_factory) -> Path:
    """The same four scenes written as a scene folder (reference layout + camera.yaml + truth)."""
    return write_dataset(tmp_path_factory.mktemp("synth") / "scenes", SMALL)


@pytest.fixture
def scene_dir_copy(small_synth_dir, tmp_path) -> Path:
    """A private, writable copy of the small scene folder (for tests that damage it)."""
    import shutil

    dst = tmp_path / "scenes"
    shutil.copytree(small_synth_dir, dst, ignore=shutil.ignore_patterns(".l2e_cache"))
    return dst
