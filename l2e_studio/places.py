"""Which scenes show the same place: a rig that did not move between them.

A targetless score learns the translation from how the parallax of near and far structure
changes between scenes. Scenes recorded without moving the rig (a checkerboard carried about in
front of a static rig, several takes of one street) show the same structure from the same
place: to the score they are one scene many times over, and every check that compares parts of
the data (halves, a second start) agrees with itself there, wrong or right. On LCECalib's static
rig (18 scenes of one courtyard) a result 2.0 deg / 20 cm from the reference scored as high as
the reference and passed every such check.

The test compares what the lidar sees in each direction: the mean range of each scene's points
per cell of ``CELL_DEG`` in azimuth and elevation (lidar frame). Two scenes show the same place
when, over the cells both see, at least ``SAME_SHARE`` agree to within ``RANGE_M`` plus
``RANGE_REL`` of the range. Measured on the dev rigs, one pair of consecutive scenes at a time:
static rigs (HITSZ, both LCECalib rigs) agree on 81-93 % of the cells; KITTI's drive 11-30 %,
OpenCalib's two streets 9 %. Something carried through the view (the board, a person) changes
a few cells only.
"""

from __future__ import annotations

import numpy as np

CELL_DEG = 1.0
RANGE_M, RANGE_REL = 0.1, 0.02
SAME_SHARE = 0.6
#: scenes that share fewer cells than this (too few points in common view) are different places
MIN_CELLS = 50
#: at most this many points (every k-th, so each scene keeps its share) are binned: 40 full-size
#: synthetic scenes (3M points) 5k each, still some 2k cells apiece; every real dev rig whole
MAX_POINTS = 200_000

_AZ = int(round(360 / CELL_DEG))
_EL = int(round(180 / CELL_DEG))


def range_views(points: np.ndarray, scene_of: np.ndarray, n_scenes: int) -> np.ndarray:
    """(S, cells) the mean range of each scene's (3, N) lidar-frame ``points`` per direction cell
    that some scene sees (nan where a scene has no point)."""
    P = np.asarray(points, dtype=np.float64)
    x, y, z = P
    r = np.sqrt(x * x + y * y + z * z)
    ok = np.isfinite(r) & (r > 0)
    az = np.floor((np.degrees(np.arctan2(y[ok], x[ok])) + 180.0) / CELL_DEG).astype(np.int64) % _AZ
    el = np.clip(np.floor((np.degrees(np.arctan2(z[ok], np.hypot(x[ok], y[ok]))) + 90.0) / CELL_DEG),
                 0, _EL - 1).astype(np.int64)
    cells, column = np.unique(el * _AZ + az, return_inverse=True)
    key = np.asarray(scene_of, dtype=np.int64)[ok] * len(cells) + column.ravel()
    count = np.bincount(key, minlength=n_scenes * len(cells)).reshape(n_scenes, -1)
    total = np.bincount(key, r[ok], minlength=n_scenes * len(cells)).reshape(n_scenes, -1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / count, np.nan)


def agreement(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the share of the cells two :func:`range_views` rows both see whose ranges agree, how many
    cells they both see), over the last axis: rows broadcast, so one scene meets many at once."""
    both = np.isfinite(a) & np.isfinite(b)
    with np.errstate(invalid="ignore"):
        close = np.abs(a - b) <= RANGE_M + RANGE_REL * np.minimum(a, b)
    n = both.sum(axis=-1)
    return (close & both).sum(axis=-1) / np.maximum(n, 1), n


def places(points: np.ndarray, scene_of: np.ndarray, n_scenes: int) -> np.ndarray:
    """(S,) int: the place of each scene, numbered in order of first appearance. A scene joins
    the first place whose first scene it agrees with (:func:`agreement` at least ``SAME_SHARE``
    over at least ``MIN_CELLS`` cells), else starts a place of its own."""
    if n_scenes == 0:
        return np.zeros(0, dtype=np.int64)
    step = -(-len(scene_of) // MAX_POINTS)
    views = range_views(np.asarray(points)[:, ::step], np.asarray(scene_of)[::step], n_scenes)
    first: list[int] = []  # the first scene of each place
    out = np.empty(n_scenes, dtype=np.int64)
    for s in range(n_scenes):
        share, n = agreement(views[first], views[s])  # this scene against every place's first at once
        match = np.flatnonzero((n >= MIN_CELLS) & (share >= SAME_SHARE))
        if match.size:
            out[s] = match[0]
        else:
            out[s] = len(first)
            first.append(s)
    return out
