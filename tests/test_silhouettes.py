"""Silhouettes against no return: a lidar point beside a gap where nothing came back (sky, beyond
the range) is an edge (stop 43), and neither a lone dropout nor the end of a cloud cut to a sector is."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from l2e_studio.calibrate import CalibrationSettings, refine, stack_scenes
from l2e_studio.scenes import Scene
from l2e_studio.scoring import edges
from l2e_studio.synth.dataset import SynthConfig, make_rig, make_scene

STEP_DEG = 0.2


def ring_scan(azimuths_deg: np.ndarray, ranges: np.ndarray, rings_deg=(-3.0, -1.0, 1.0, 3.0)) -> np.ndarray:
    """(N, 3) points of a spinning lidar's rings (lidar frame, z up) at the given azimuths and ranges;
    a range of nan is a missing return."""
    pts = []
    for el in np.radians(rings_deg):
        az = np.radians(azimuths_deg)
        d = np.c_[np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.full(az.shape, np.sin(el))]
        pts.append(d * ranges[:, None])
    p = np.concatenate(pts)
    return p[np.isfinite(p).all(axis=1)]


def weights_by_azimuth(points: np.ndarray) -> dict[float, float]:
    w = edges.lidar_edge_weights(points.astype(np.float32), np.full(len(points), 100.0, np.float32))
    az = np.round(np.degrees(np.arctan2(points[:, 1], points[:, 0])), 3)
    return {a: float(w[az == a].max()) for a in np.unique(az)}


def test_an_object_against_the_sky_has_its_silhouette_as_edges() -> None:
    az = np.arange(-180.0, 180.0, STEP_DEG)
    ranges = np.full(az.shape, 8.0)  # a wall all round ...
    ranges[(az > -20) & (az < 20)] = np.nan  # ... but ahead the sky ...
    ranges[(az > -5.05) & (az < 5.05)] = 4.0  # ... and a post in front of it
    w = weights_by_azimuth(ring_scan(az, ranges))
    post = [a for a in w if -5.05 < a < 5.05]
    for a in (min(post), max(post)):  # the post's two sides, each against the sky
        assert w[a] == edges.SILHOUETTE_WEIGHT
    wall = [a for a in w if not -20 < a < 20]
    for a in (max(a for a in wall if a < 0), min(a for a in wall if a > 0)):  # the wall's ends at the sky
        assert w[a] == edges.SILHOUETTE_WEIGHT
    inside = [a for a in post if min(post) < a < max(post)]
    assert max(w[a] for a in inside) < edges.MIN_WEIGHT  # the post's face is no edge
    assert max(w[a] for a in wall if a < -25 or a > 25) < edges.MIN_WEIGHT


def test_a_lone_dropout_is_no_edge_and_a_cloud_cut_to_a_sector_has_no_edge_at_its_ends() -> None:
    az = np.arange(-180.0, 180.0, STEP_DEG)
    ranges = np.full(az.shape, 8.0)
    ranges[np.argmin(np.abs(az - 10.0))] = np.nan  # one pulse lost on a plain wall
    w = weights_by_azimuth(ring_scan(az, ranges))
    assert max(w.values()) < edges.MIN_WEIGHT
    # the same wall cut to a camera's view of 60 deg: its ends are where the data stops, not
    # silhouettes; nor where the file keeps its lost returns as zeros (an organised cloud)
    sector = (az > -30) & (az < 30)
    cut = ring_scan(az[sector], np.full(sector.sum(), 8.0))
    for cloud in (cut, np.vstack([cut, np.zeros((500, 3))])):
        w = weights_by_azimuth(cloud)
        assert max(w.values()) < edges.MIN_WEIGHT


def test_a_lidar_that_looks_up_at_the_sky_finds_its_peak_at_the_truth() -> None:
    """The synthetic OS1-128 (+-22.5 deg) under every image trap, the sky's returns lost: without
    silhouettes the edge score's 6-DoF peak sat 0.22 deg / 1 cm off the truth at 7 deviations
    above its far field; its upper half alone peaked 0.64 deg off, the truth below its far field."""
    from l2e_studio.peaks import significance

    config = SynthConfig(n_scenes=8, map_kind="image", realism=True, lidar="os128", seed=11)
    camera, truth, _ = make_rig(config)
    scenes = []
    for i in range(config.n_scenes):
        points, intensity, grey = make_scene(config, i, truth, camera)
        scenes.append(Scene(f"scene_{i:03d}", points, intensity, grey.astype(np.float32), "image"))
    settings = CalibrationSettings(objective="edges")
    stack = stack_scenes(scenes, camera, truth, replace(settings, translation_bound=0.5, rotation_bound_deg=20.0))
    final = stack.aimed_at(truth).with_sigma(settings.sigma)
    end = refine(final, truth, replace(settings, global_search=False, coarse_to_fine=False))
    deg, m = end.error_to(truth)
    assert deg < 0.1 and m < 0.005
    assert significance(final, truth, settings).z > 15.0
