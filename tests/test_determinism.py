"""The same inputs give the same answer to the bit, wherever the arrays sit in memory and in
whichever process: a last-bit difference in a map or a projection moves an optimiser's path,
and near a verdict's threshold it turned `trusted-rotation` into `not-trusted` between two runs
of one command (rig 1+2 of the real data, from one 5 deg seed)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from l2e_studio.geometry import Extrinsic
from l2e_studio.scoring import edges


def _at_offsets(a: np.ndarray, n: int = 16):
    """Copies of ``a`` starting at n successive element offsets of a larger buffer (other
    alignments than a fresh array's)."""
    flat = a.reshape(-1)
    for off in range(n):
        buf = np.empty(flat.size + n, a.dtype)
        view = buf[off:off + flat.size]
        view[:] = flat
        yield view.reshape(a.shape)


def test_the_edge_map_is_the_same_wherever_its_image_sits():
    rng = np.random.default_rng(4)
    image = (rng.random((181, 243)) * 200).astype(np.float32)
    maps = {edges.edge_map(img, 1.5, (121, 90)).tobytes() for img in _at_offsets(image)}
    mags = {edges.gradient_magnitude(img).tobytes() for img in _at_offsets(image)}
    assert len(maps) == 1 and len(mags) == 1


def test_the_transform_is_the_same_wherever_the_points_sit():
    rng = np.random.default_rng(5)
    ext = Extrinsic.from_params(np.array([0.1, -0.2, 0.3, 0.01, 0.02, -0.03]))
    for dtype in (np.float32, np.float64):
        points = (rng.normal(size=(75_001, 3)) * 20).astype(dtype)
        got = {ext.transform(p).tobytes() for p in _at_offsets(points)}
        assert len(got) == 1, dtype
        # nor on its neighbours: a point comes out the same in a scan and in any part of it
        whole = ext.transform(points)
        for a, b in ((1, None), (0, 7), (5, 20_000)):
            assert ext.transform(points[a:b]).tobytes() == whole[a:b].tobytes(), (dtype, a, b)
        want = points.astype(np.float64) @ ext.R.T + ext.translation
        assert np.allclose(ext.transform(points), want, rtol=1e-6 if dtype == np.float32 else 1e-12, atol=1e-5)


_RUN = """
import json, sys
import numpy as np
from l2e_studio.calibrate import CalibrationSettings, calibrate, stack_scenes
from l2e_studio.scenes import load_scene_folder
from l2e_studio.verdict import judge
ss = load_scene_folder(sys.argv[1])
seed = ss.seed.perturbed([0.03, -0.02, 0.02], np.radians([0.8, -0.6, 0.5]))
settings = CalibrationSettings(objective="edges")
stack = stack_scenes(ss.scenes, ss.camera, seed, settings)
r = calibrate(stack, None, seed, settings)
v = judge(stack, r, settings)
print(json.dumps([r.extrinsic.params.tolist(), r.score_result, v.status, [c.detail for c in v.checks]]))
"""


def test_two_processes_give_the_same_calibration_and_verdict(small_synth_dir: Path):
    """The edge objective (camera-image maps, where the last-bit differences arose) and its
    verdict, run in two fresh processes with their own memory layouts and hash seeds."""
    outs = []
    for hashseed in ("1", "2"):
        env = {**__import__("os").environ, "PYTHONHASHSEED": hashseed}
        p = subprocess.run([sys.executable, "-c", _RUN, str(small_synth_dir)], capture_output=True, text=True,
                           env=env, timeout=600)
        assert p.returncode == 0, p.stderr[-2000:]
        outs.append(json.loads(p.stdout.strip().splitlines()[-1]))
    assert outs[0] == outs[1]
