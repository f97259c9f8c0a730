"""All scenes stacked into flat arrays, and the paper's MI and the edge score evaluated over them.

Every scene is loaded once into one set of arrays: lidar points (3, N) float32 sorted by scene,
their intensity bins, and one zero-padded (S, H+2, W+2) stack of prepared maps. One evaluation
is then one projection, one gather and one count over all points of all scenes.

:meth:`SceneStack.mi` is the paper's MI, for reporting: points that land inside the image read
the map at the nearest pixel, hard histogram bins, Silverman widths from the data.
:meth:`SceneStack.objective` hands the optimiser its smooth form (:mod:`.smooth`).
"""
from __future__ import annotations

import threading
import weakref
from dataclasses import dataclass, field, replace
from functools import cache, cached_property
from typing import Callable, Sequence

import numpy as np

from .. import compiled
from ..camera import CameraModel
from ..geometry import Extrinsic, in_image, project_points
from ..places import places
from ..pool import CHUNK, WORKERS, run_chunks, run_tasks
from ..scenes import Scene
from ..score_maps import CLIP, rows, scan_directions, stack_maps
from ..scoring import EDGE_GRADIENTS, OBJECTIVES
from ..scoring import edges
from ..scoring.edges import MIN_WEIGHT, lidar_edge_weights
from ..scoring.mi import N_BINS, mi_from_joint_histogram
from .smooth import MIN_DEPTH, EdgeObjective, MapObjective, MIObjective

#: How many smoothings of one stack :meth:`SceneStack.with_sigma` keeps (the schedule's three stages,
#: and one more a caller asks for, e.g. a slider's).
SMOOTHED_KEEP = 4
_CACHES_LOCK = threading.Lock()  # guards the smoothings and scores each stack keeps
#: How many scores :meth:`SceneStack.score` remembers per stack: a run scores its seed and result,
#: and the verdict asks for them again on the data and its halves (each 40 ms on 40 full-size scenes)
SCORES_KEEP = 16
#: The edge maps are prepared again when the lidar's axis turns further than this (deg) from the
#: extrinsic they were prepared for: the gradient then leaks at most sin(3 deg), 5 %, along the lines.
SCAN_REAIM_DEG = 3.0


@dataclass(frozen=True)
class SceneStack:
    """Scenes stacked for fast evaluation. Build with :meth:`build`."""

    camera: CameraModel
    names: tuple[str, ...]
    points: np.ndarray  # (3, N) float32, lidar frame, sorted by scene
    l_bins: np.ndarray  # (N,) int32, lidar intensity 0..255
    scene_of: np.ndarray  # (N,) int32, index of each point's scene
    maps: np.ndarray  # (S, H+2, W+2) float32, prepared maps with a one-pixel zero border
    map_kinds: tuple[str, ...]
    raw_maps: tuple[np.ndarray, ...]  # the unprepared maps, for re-smoothing
    sigma: float  # map smoothing in full-resolution pixels
    scale: float = 1.0  # maps (and ``camera``) are the full-resolution ones resized by this
    full_camera: CameraModel | None = None
    objective_name: str = "mi"  # what the maps are prepared for and :meth:`score` reports
    weights: np.ndarray | None = None  # (N,) float32 edge weights (the ``edges`` objective)
    gradient: str = "magnitude"  # what the edge maps read (``scoring.EDGE_GRADIENTS``)
    scan: np.ndarray | None = None  # (H, W, 2) float32 scan-line directions at full resolution (``scan-lines``)
    scan_axis: np.ndarray | None = None  # the lidar's z axis in the camera frame that ``scan`` was projected for
    #: the stacks :meth:`with_sigma` derived from this one, by (sigma, scale), the latest
    #: ``SMOOTHED_KEEP``: every climb of a global search, and the verdict's probes after it, climb
    #: the same stages, whose maps are then prepared once (a :meth:`select`ion shares them; stacks
    #: derived otherwise start without)
    _smoothed: dict = field(default_factory=dict, init=False, repr=False, compare=False)
    #: the latest ``SCORES_KEEP`` scores :meth:`score` computed, by extrinsic and pooled scenes
    _scores: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    # --- construction ------------------------------------------------------------------
    @classmethod
    def build(
        cls,
        scenes: Sequence[Scene],
        camera: CameraModel,
        sigma: float = 5.0,
        reference: Extrinsic | None = None,
        reach_m: float = 0.5,
        reach_deg: float = 20.0,
        objective: str = "mi",
        gradient: str = "magnitude",
    ) -> "SceneStack":
        """Stack ``scenes`` for ``objective`` (``mi`` or ``edges``); with a ``reference``
        extrinsic, drop points that cannot reach the image for any extrinsic within
        ``reach_m`` / ``reach_deg`` of it (an over-estimate). For ``edges`` only the points on
        lidar edges are kept, with their weights; with ``gradient="scan-lines"`` the image
        gradient is read across the scan lines as the ``reference`` projects them (without one:
        across the image rows)."""
        if not scenes:
            raise ValueError("no scenes to stack")
        if objective not in OBJECTIVES:
            raise ValueError(f"unknown objective {objective!r}; expected one of {', '.join(OBJECTIVES)}")
        if gradient not in EDGE_GRADIENTS:
            raise ValueError(f"unknown edge gradient {gradient!r}; expected one of {', '.join(EDGE_GRADIENTS)}")
        pts, bins, owner, weights = [], [], [], []
        for i, sc in enumerate(scenes):
            if sc.event_map.shape != (camera.height, camera.width):
                raise ValueError(
                    f"scene {sc.name}: map is {sc.event_map.shape[1]}x{sc.event_map.shape[0]}, "
                    f"camera expects {camera.width}x{camera.height}"
                )
            p = np.asarray(sc.points, dtype=np.float32)
            keep = np.ones(len(p), dtype=bool)
            if reference is not None:
                keep &= _reachable(p, camera, reference, reach_m, reach_deg)
            if objective == "edges":
                w = lidar_edge_weights(p, sc.intensity)
                keep &= w >= MIN_WEIGHT
                weights.append(w[keep])
            pts.append(p[keep])
            bins.append(np.clip(np.rint(sc.intensity[keep]), 0, N_BINS - 1).astype(np.int32))
            owner.append(np.full(len(pts[-1]), i, dtype=np.int32))
        raw = tuple(np.asarray(sc.event_map, dtype=np.float32) for sc in scenes)
        kinds = tuple(sc.map_kind for sc in scenes)
        scan = None
        if objective == "edges" and gradient == "scan-lines":
            scan = scan_directions(camera, reference) if reference is not None else rows(camera)
        return cls(
            camera=camera,
            names=tuple(sc.name for sc in scenes),
            points=np.ascontiguousarray(np.concatenate(pts).T),
            l_bins=np.concatenate(bins),
            scene_of=np.concatenate(owner),
            maps=stack_maps(raw, kinds, sigma, objective=objective, scan=scan),
            map_kinds=kinds,
            raw_maps=raw,
            sigma=float(sigma),
            full_camera=camera,
            objective_name=objective,
            weights=np.concatenate(weights) if objective == "edges" else None,
            gradient=gradient,
            scan=scan,
            scan_axis=None if scan is None or reference is None else reference.R[:, 2].copy(),
        )

    def with_sigma(self, sigma: float, scale: float = 1.0) -> "SceneStack":
        """The same points over maps smoothed with another sigma (full-resolution pixels),
        optionally at a reduced resolution (``scale`` < 1) for cheap coarse stages. Asked again,
        the same stack (the latest ``SMOOTHED_KEEP`` are kept)."""
        if sigma == self.sigma and scale == self.scale:
            return self
        key = (float(sigma), float(scale))
        with _CACHES_LOCK:
            hit = self._smoothed.get(key)
        if hit is not None:
            return hit
        full = self.full_camera or self.camera
        camera = full if scale == 1.0 else full.scaled(scale)
        maps = stack_maps(self.raw_maps, self.map_kinds, sigma, (camera.width, camera.height), self.objective_name, self.scan)
        out = replace(self, maps=maps, sigma=float(sigma), scale=float(scale), camera=camera, full_camera=full)
        with _CACHES_LOCK:  # (two threads asking at once both prepare; either result is the same)
            while len(self._smoothed) >= SMOOTHED_KEEP:  # bounded: the oldest goes (a slider may ask for many)
                self._smoothed.pop(next(iter(self._smoothed)))
            self._smoothed[key] = out
        return out

    def aimed_at(self, extrinsic: Extrinsic) -> "SceneStack":
        """The stack whose edge maps read across the scan lines as ``extrinsic`` projects them:
        itself while the lidar's axis is within :data:`SCAN_REAIM_DEG` of the one its maps were
        prepared for, else the same points over maps prepared again (a seed tuned far by hand, a
        rig turned on its side, must not be scored across the old seed's scan lines)."""
        if self.scan is None:  # the edge maps read every orientation (or the stack is MI's)
            return self
        axis = extrinsic.R[:, 2]
        if self.scan_axis is not None and float(axis @ self.scan_axis) >= np.cos(np.radians(SCAN_REAIM_DEG)):
            return self
        full = self.full_camera or self.camera
        scan = scan_directions(full, extrinsic)
        maps = stack_maps(self.raw_maps, self.map_kinds, self.sigma, (self.camera.width, self.camera.height),
                          self.objective_name, scan)
        return replace(self, maps=maps, scan=scan, scan_axis=axis.copy())

    def with_map(self, index: int, raw_map: np.ndarray) -> "SceneStack":
        """The same stack with scene ``index``'s map replaced by ``raw_map`` (unprepared, full
        resolution); only that map is prepared again, the others are shared, not recomputed."""
        if not 0 <= index < self.n_scenes:
            raise IndexError(f"scene index {index} is outside 0..{self.n_scenes - 1}")
        raw = np.asarray(raw_map, dtype=np.float32)
        if raw.shape != self.raw_maps[index].shape:
            raise ValueError(f"scene {self.names[index]}: the new map is {raw.shape[1]}x{raw.shape[0]}, "
                             f"the stack's are {self.raw_maps[index].shape[1]}x{self.raw_maps[index].shape[0]}")
        size = (self.camera.width, self.camera.height)
        maps = self.maps.copy()  # the old stack stays valid for whoever holds it (immutable)
        maps[index] = stack_maps([raw], [self.map_kinds[index]], self.sigma, size, self.objective_name, self.scan)[0]
        raw_maps = self.raw_maps[:index] + (raw,) + self.raw_maps[index + 1:]
        return replace(self, maps=maps, raw_maps=raw_maps)

    def select(self, keep: np.ndarray) -> "SceneStack":
        """Keep the points where the boolean mask ``keep`` is true, or those at the increasing
        indices ``keep`` (the maps are shared, not copied, the smoothings :meth:`with_sigma` has
        prepared included)."""
        keep = np.asarray(keep)
        keep = keep if keep.dtype == bool else keep.astype(np.intp)
        points = dict(points=np.ascontiguousarray(self.points[:, keep]), l_bins=self.l_bins[keep],
                      scene_of=self.scene_of[keep], weights=None if self.weights is None else self.weights[keep])
        out = replace(self, **points)
        # the smoothings this stack prepared serve the selection too (the same maps, its points):
        # a part of the data climbs the stages of a run without preparing them again
        with _CACHES_LOCK:
            prepared = list(self._smoothed.items())
        out._smoothed.update((key, replace(st, **points)) for key, st in prepared)
        return out

    def subset(self, scenes: Sequence[int] | np.ndarray) -> "SceneStack":
        """The stack of only some scenes (indices or a boolean mask), in their original order."""
        idx = np.asarray(scenes)
        idx = np.flatnonzero(idx) if idx.dtype == bool else np.unique(idx)
        if np.array_equal(idx, np.arange(self.n_scenes)):
            # all of them: no array copied (the caches derived from the maps stay valid), but a stack of
            # its own, so the smoothings a run prepares live as long as the run, not the caller's stack
            return replace(self)
        renumber = np.full(self.n_scenes, -1, dtype=np.int32)
        renumber[idx] = np.arange(idx.size, dtype=np.int32)
        keep = renumber[self.scene_of] >= 0
        return replace(
            self,
            names=tuple(self.names[i] for i in idx),
            points=np.ascontiguousarray(self.points[:, keep]),
            l_bins=self.l_bins[keep],
            scene_of=renumber[self.scene_of[keep]],
            weights=None if self.weights is None else self.weights[keep],
            maps=self.maps[idx],
            map_kinds=tuple(self.map_kinds[i] for i in idx),
            raw_maps=tuple(self.raw_maps[i] for i in idx),
        )

    def thinned(self, max_points: int | None) -> "SceneStack":
        """At most ``max_points`` points: every k-th in scan order, so the sample stays even."""
        if max_points is None or self.n_points <= max_points:
            return self
        return self.select(evenly(np.arange(self.n_points), max_points))

    @property
    def n_scenes(self) -> int:
        return len(self.names)

    @property
    def n_points(self) -> int:
        return self.points.shape[1]

    @cached_property
    def starts(self) -> np.ndarray:
        """(S + 1,) where each scene's points begin in the stacked arrays, and the end: scene
        ``s`` is ``starts[s]:starts[s + 1]`` (the points are sorted by scene)."""
        return np.searchsorted(self.scene_of, np.arange(self.n_scenes + 1))

    @cached_property
    def places(self) -> np.ndarray:
        """(S,) the place each scene was recorded at (:func:`l2e_studio.places.places`): the
        scenes of a rig that did not move between them share one."""
        return places(self.points, self.scene_of, self.n_scenes)

    @property
    def n_places(self) -> int:
        """How many different places the scenes show (:attr:`places`)."""
        return int(self.places.max()) + 1 if self.n_scenes else 0

    # --- projection and the paper's MI -------------------------------------------------------
    def project(self, extrinsic: Extrinsic) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (N, 2) of every point and the mask of those inside the image."""
        return _project_inside(self.points, extrinsic.R.astype(np.float32),
                               extrinsic.translation.astype(np.float32), self.camera)

    def pixels(self, extrinsic: Extrinsic) -> np.ndarray:
        """(N,) int32 index ``row * W + col`` of the pixel nearest each projected point in its
        scene's map, -1 for points off the image (compiled, on the worker threads)."""
        R = extrinsic.R.astype(np.float32)
        t = extrinsic.translation.astype(np.float32)
        out = np.empty(self.n_points, np.int32)
        run_chunks(lambda a, b: compiled.pixel_index(self.points[:, a:b], R, t, self.camera, MIN_DEPTH, out[a:b]),
                    self.n_points)
        return out

    def joint_histograms(self, extrinsic: Extrinsic, per_scene: bool = True) -> np.ndarray:
        """(S, 256, 256) int32 joint (L, E) counts per scene, nearest-pixel lookup, in-image
        points; with ``per_scene=False`` the (1, 256, 256) counts of all scenes pooled."""
        joints = self._scene_joints(extrinsic) if per_scene else self._pooled_joint(extrinsic)[None]
        return joints.reshape(-1, N_BINS, N_BINS)

    def _count_scene(self, s: int, R: np.ndarray, t: np.ndarray, e_bins: np.ndarray, starts: np.ndarray,
                     hist: np.ndarray) -> None:
        """Add scene ``s``'s (L, E) pairs at ``R, t`` to ``hist`` (65536 int32), chunk by chunk."""
        a, b = int(starts[s]), int(starts[s + 1])
        pix = np.empty(min(CHUNK, b - a), np.int32)
        for c in range(a, b, CHUNK):
            d = min(c + CHUNK, b)
            index = compiled.pixel_index(self.points[:, c:d], R, t, self.camera, MIN_DEPTH, pix)
            compiled.count_pairs(index, self.l_bins[c:d], e_bins[s], hist)

    def _scene_joints(
        self, extrinsic: Extrinsic, then: Callable[[int, np.ndarray], None] | None = None
    ) -> np.ndarray:
        """(S, 65536) int32 joint counts, one scene per task on the worker threads; ``then(s,
        counts)`` runs in the same task once scene ``s`` is counted (e.g. its MI)."""
        R, t = extrinsic.R.astype(np.float32), extrinsic.translation.astype(np.float32)
        e_bins = _e_bins(self.maps)
        starts = self.starts
        joints = np.zeros((self.n_scenes, N_BINS * N_BINS), np.int32)

        def scene(s: int) -> None:
            self._count_scene(s, R, t, e_bins, starts, joints[s])
            if then is not None:
                then(s, joints[s])

        run_tasks(scene, range(self.n_scenes))
        return joints

    def _pooled_joint(self, extrinsic: Extrinsic, pooled: np.ndarray | None = None,
                      e_bins: np.ndarray | None = None) -> np.ndarray:
        """(65536,) int32 joint counts of the scenes in ``pooled`` (a boolean mask; default all)
        summed: one histogram per worker, not per scene (a third of the time on 40 scenes of 2.5k
        points, where zeroing and summing 40 histograms cost more than counting). The counts are
        integers, so the sum is the per-scene histograms' to the last bit. ``e_bins``: (S, H*W)
        the maps' E bins at this stack's camera (default: its prepared maps')."""
        R, t = extrinsic.R.astype(np.float32), extrinsic.translation.astype(np.float32)
        e_bins = _e_bins(self.maps) if e_bins is None else e_bins
        starts = self.starts
        chosen = np.arange(self.n_scenes) if pooled is None else np.flatnonzero(pooled)
        groups = [g for g in np.array_split(chosen, min(WORKERS, max(chosen.size, 1))) if g.size]
        joints = np.zeros((max(len(groups), 1), N_BINS * N_BINS), np.int32)

        def group(k: int) -> None:
            for s in groups[k]:
                self._count_scene(int(s), R, t, e_bins, starts, joints[k])

        run_tasks(group, range(len(groups)))
        return joints.sum(axis=0, dtype=np.int32) if len(joints) > 1 else joints[0]

    def mi(
        self, extrinsic: Extrinsic, per_scene: bool = True, pooled: np.ndarray | None = None
    ) -> tuple[float, np.ndarray]:
        """The paper's MI at ``extrinsic``: (the scenes pooled, per scene; NaN without ``per_scene``).

        ``pooled`` (a boolean mask over the scenes) picks the scenes whose histograms are summed
        for the first value; by default all. NaN when the mask picks none. Each scene's value
        is computed in the task that counts its points.
        """
        per = np.full(self.n_scenes, np.nan)
        mask = np.ones(self.n_scenes, bool) if pooled is None else np.asarray(pooled, dtype=bool)
        if not per_scene:
            total = mi_from_joint_histogram(self._pooled_joint(extrinsic, mask).reshape(N_BINS, N_BINS))
            return (total if mask.any() else float("nan")), per

        def scene_mi(s: int, counts: np.ndarray) -> None:
            per[s] = mi_from_joint_histogram(counts.reshape(N_BINS, N_BINS))

        joints = self._scene_joints(extrinsic, scene_mi)
        total = float("nan")
        if mask.any():
            pooled_counts = joints.sum(axis=0) if mask.all() else joints[mask].sum(axis=0)
            total = mi_from_joint_histogram(pooled_counts.reshape(N_BINS, N_BINS))
        return total, per

    def raw_mi(self) -> Callable[[Extrinsic], float]:
        """The paper's MI of all scenes pooled on the unsmoothed maps at full resolution, as a
        function of the extrinsic (the verdict's second score for event maps). The maps' E bins
        are taken once from the raw maps, clipped as :func:`stack_maps` clips them: the same
        values as :meth:`mi` of ``with_sigma(0.0)``, without preparing that stack's float maps
        (150 MB for 40 full-size scenes, a sixth of a verdict's work on them). The bins are taken
        at the first call (the verdict's, beside its second start's climb)."""
        full = self if self.scale == 1.0 else replace(self, camera=self.full_camera, scale=1.0)
        bins = cache(lambda: _raw_e_bins(self.raw_maps, self.map_kinds))
        return lambda ext: mi_from_joint_histogram(full._pooled_joint(ext, e_bins=bins()).reshape(N_BINS, N_BINS))

    # --- the stack's own score (what the optimiser climbs, in its reporting form) -------------
    def edge_scores(
        self, extrinsic: Extrinsic, per_scene: bool = True, pooled: np.ndarray | None = None
    ) -> tuple[float, np.ndarray]:
        """The edge score at ``extrinsic`` (nearest-pixel lookup; a point off the image reads
        "no edge"): (the scenes pooled, per scene), as :meth:`mi` returns them."""
        if self.weights is None:
            raise ValueError("this stack was not built for the edges objective")
        pix = self.pixels(extrinsic)
        S = self.n_scenes
        starts = self.starts
        num = np.zeros(S)

        def scene(s: int) -> None:
            a, b = starts[s], starts[s + 1]
            num[s] = compiled.edge_sum(pix[a:b], self.weights[a:b], self.maps[s], edges.OFFSET, edges.SCALE)

        run_tasks(scene, range(S))
        den = np.bincount(self.scene_of, weights=self.weights, minlength=S)
        per = np.where(den > 0, num / np.maximum(den, 1e-12), np.nan) if per_scene else np.full(S, np.nan)
        return _pooled_edges(num, den, pooled), per

    def score(
        self, extrinsic: Extrinsic, per_scene: bool = True, pooled: np.ndarray | None = None
    ) -> tuple[float, np.ndarray]:
        """The score of the stack's objective at ``extrinsic`` (the paper's MI, or the edge
        score): (the scenes pooled, per scene). Asked again for the same extrinsic and scenes, the
        same values, not computed again (the latest ``SCORES_KEEP``; the pooled value is the same
        with or without ``per_scene``: integer counts, or sums, summed alike)."""
        key = (extrinsic.rotvec.tobytes(), extrinsic.translation.tobytes(),
               None if pooled is None else np.asarray(pooled, dtype=bool).tobytes())
        with _CACHES_LOCK:
            hit = self._scores.get(key)
        if hit is not None and (hit[1] is not None or not per_scene):
            return hit[0], hit[1].copy() if per_scene else np.full(self.n_scenes, np.nan)
        scores = self.edge_scores if self.objective_name == "edges" else self.mi
        total, per = scores(extrinsic, per_scene, pooled)
        with _CACHES_LOCK:
            while len(self._scores) >= SCORES_KEEP:
                self._scores.pop(next(iter(self._scores)))
            self._scores[key] = (total, per.copy() if per_scene else None)
        return total, per

    def scores(self, extrinsics: Sequence[Extrinsic]) -> np.ndarray:
        """(P,) the scenes' pooled :meth:`score` at each of ``extrinsics``, the same values to the
        last bit, counted scene by scene across all of them: a scene's map is read from cache by
        every pose, where one pose after the other reads every map from memory again (the
        verdict's 48 far-field poses on 40 full-size scenes thinned to 100k points: 60 ms,
        160-185 ms one by one; 2 cores)."""
        P, S = len(extrinsics), self.n_scenes
        Rs = np.array([e.R for e in extrinsics], np.float32).reshape(P, 3, 3)
        ts = np.array([e.translation for e in extrinsics], np.float32).reshape(P, 3)
        starts = self.starts
        bounds = np.linspace(0, P, min(WORKERS, max(P, 1)) + 1).astype(int)  # the poses, one group per worker
        groups = [(a, b) for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
        out = np.full(P, np.nan)
        if self.objective_name == "edges":
            if self.weights is None:
                raise ValueError("this stack was not built for the edges objective")
            sums = np.zeros((P, S))
            run_tasks(lambda ab: compiled.edge_sums_at_poses(
                self.points, self.weights, starts, Rs[ab[0]:ab[1]], ts[ab[0]:ab[1]], self.camera, MIN_DEPTH, self.maps,
                edges.OFFSET, edges.SCALE, sums[ab[0]:ab[1]]), groups)
            den = np.bincount(self.scene_of, weights=self.weights, minlength=S)
            out[:] = [_pooled_edges(num, den) for num in sums]
            return out
        hists = np.zeros((P, N_BINS * N_BINS), np.int32)
        e_bins = _e_bins(self.maps)

        def group(ab: tuple[int, int]) -> None:  # a group of poses counted, then their MI, in one task
            a, b = ab
            compiled.count_pairs_at_poses(self.points, self.l_bins, starts, Rs[a:b], ts[a:b], self.camera, MIN_DEPTH,
                                          e_bins, hists[a:b])
            if S:
                out[a:b] = [mi_from_joint_histogram(h.reshape(N_BINS, N_BINS)) for h in hists[a:b]]

        run_tasks(group, groups)
        return out

    # --- the optimiser's objective -------------------------------------------------------
    def objective(
        self, base: Extrinsic, start: Extrinsic | None = None, max_points: int | None = None,
        seen_from: Sequence[Extrinsic] = (),
    ) -> "MapObjective":
        """The differentiable score as a function of a correction of ``base``, over the points
        that land in the image at ``start`` (default: ``base``) or at any of ``seen_from`` (one
        point set for climbs from many starts), thinned to ``max_points``."""
        start = base if start is None else start
        seen = self.pixels(start) >= 0
        for extrinsic in seen_from:
            seen |= self.pixels(extrinsic) >= 0
        inside = np.flatnonzero(seen)
        cls = EdgeObjective if self.objective_name == "edges" else MIObjective
        return cls(self.select(evenly(inside, max_points)), base, start)  # one copy, not two


#: The E bins of the last few map stacks, keyed by the maps array they came from: stacks made by
#: ``select``, and ``subset`` of all scenes, share their maps, so every evaluation of the
#: readout's stack (and of a verdict's half-scene stacks) reuses one derivation.
_E_BINS: list[tuple[weakref.ref, np.ndarray]] = []
_E_BINS_KEEP = 3
_E_BINS_LOCK = threading.Lock()


def evenly(indices: np.ndarray, max_points: int | None) -> np.ndarray:
    """At most ``max_points`` of ``indices``: every k-th, so a sample in scan order stays even."""
    if max_points is None or indices.size <= max_points:
        return indices
    return indices[:: -(-indices.size // max_points)]


def _pooled_edges(num: np.ndarray, den: np.ndarray, pooled: np.ndarray | None = None) -> float:
    """The edge score of the scenes ``pooled`` (default all) from their weighted sums ``num`` and
    weights ``den`` (nan where none is picked or none has weight)."""
    mask = np.ones(num.size, dtype=bool) if pooled is None else np.asarray(pooled, dtype=bool)
    return float(num[mask].sum() / den[mask].sum()) if mask.any() and den[mask].sum() > 0 else float("nan")


def _e_bins(maps: np.ndarray) -> np.ndarray:
    """(S, H*W) uint8: each map pixel's E bin for the paper's MI (nearest bin), cached while
    ``maps`` lives (maps are never written after stacking)."""
    with _E_BINS_LOCK:
        for ref, bins in _E_BINS:
            if ref() is maps:
                return bins
    S, Hp, Wp = maps.shape
    bins = np.empty((S, Hp - 2, Wp - 2), np.uint8)
    run_tasks(lambda s: compiled.e_bins(maps[s], bins[s]), range(S))
    bins = bins.reshape(S, -1)
    with _E_BINS_LOCK:
        live = [(r, b) for r, b in _E_BINS if r() is not None]
        _E_BINS[:] = live[-(_E_BINS_KEEP - 1):] + [(weakref.ref(maps), bins)]
    return bins


def _raw_e_bins(raw: Sequence[np.ndarray], kinds: Sequence[str]) -> np.ndarray:
    """(S, H*W) uint8: each raw map's pixels clipped to its kind's range (:data:`CLIP`), at the
    nearest E bin: what :func:`_e_bins` gives for the maps :func:`stack_maps` prepares at sigma 0."""
    S, (H, W) = len(raw), raw[0].shape
    bins = np.empty((S, H * W), np.uint8)

    def scene(s: int) -> None:
        m = np.clip(np.asarray(raw[s], dtype=np.float32).reshape(-1), 0.0, CLIP[kinds[s]])
        np.rint(m, out=m)
        bins[s] = np.minimum(m, 255.0)

    run_tasks(scene, range(S))
    return bins


def _project_inside(points: np.ndarray, R: np.ndarray, t: np.ndarray, camera: CameraModel):
    """Pixel coordinates (N, 2) of (3, N) lidar points, and the mask of those in the image."""
    pc = R @ points
    pc += t[:, None]
    uv, front = project_points(pc.T, camera)
    return uv, front & (pc[2] > MIN_DEPTH) & in_image(uv, camera)


def _reachable(points: np.ndarray, camera: CameraModel, ref: Extrinsic, reach_m: float, reach_deg: float) -> np.ndarray:
    """Points that may project into the image for some extrinsic near ``ref`` (a superset)."""
    pc = ref.transform(points)
    z = pc[:, 2]
    rng = np.linalg.norm(pc, axis=1)
    # widen the field of view by the rotation reach plus the angle the translation reach subtends
    slack = np.radians(reach_deg) + np.arcsin(np.clip(reach_m / np.maximum(rng, 1e-6), 0.0, 1.0))
    half_w = np.arctan2(max(camera.K[0, 2], camera.width - camera.K[0, 2]), camera.K[0, 0])
    half_h = np.arctan2(max(camera.K[1, 2], camera.height - camera.K[1, 2]), camera.K[1, 1])
    if camera.model == "equidistant" or camera.is_distorted:
        half_w, half_h = half_w * 1.3, half_h * 1.3  # distortion can widen the view
    ang_x = np.abs(np.arctan2(pc[:, 0], z))
    ang_y = np.abs(np.arctan2(pc[:, 1], z))
    ok = np.isfinite(pc).all(axis=1) & (rng > MIN_DEPTH)
    return ok & (ang_x <= half_w + slack) & (ang_y <= half_h + slack)
