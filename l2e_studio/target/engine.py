"""``calibrate_target``: the checkerboard method end to end, returning the engine's CalibrationResult.

1. the board in every image (:mod:`.detect`, cached);
2. the board in every scan, searched around where the seed puts the camera's board
   (:func:`.lidar.search_board`);
3. the closed-form estimate from the planes, then the robust solve (:mod:`.solve`);
4. the boards cut again out of every scan at the solved extrinsic (:func:`.lidar.crop_board`:
   the outline as the camera sees it, which leaves out the person holding the board and its
   stand), solved again, twice: the answer then depends on the seed only through which boards
   were found, so seeds 5 deg / 20 cm apart end at the same point;
5. frames whose residuals disagree with the others are left out with the reason, and solved
   again; the uncertainty, each frame's residuals and leave-one-frame-out moves are recorded.

Frames named in ``exclude`` are left out by the user (the app's click); they are still
detected and reported.
"""

from __future__ import annotations

import hashlib
import io
import os
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Collection, Sequence

import numpy as np

from ..atomic import atomic_write_bytes
from ..cachedir import user_cache_dir
from ..calibrate import CalibrationResult, CalibrationSettings, Progress
from ..camera import CameraModel
from ..errors import InputError
from ..geometry import Extrinsic
from ..io.lidar import load_lidar
from ..scenes import Scene
from .board import Board
from .detect import Detection, detect_cached
from .lidar import LidarBoard, crop_board, search_board
from .solve import (EDGE_SIGMA_M, PLANE_SIGMA_M, Observability, TargetFrame, closed_form, frame_residuals,
                    leave_one_out, observability, residuals_at, solve)

OBJECTIVE = "board planes"  # CalibrationResult.objective of this method; score = -RMS point-to-plane distance (mm)
MIN_FRAMES = 3
SETTLE_CROPS = 3  # crops after the scheduled refinements, until they hold the same points as the last


@dataclass(frozen=True)
class TargetSettings:
    """What the target method does. ``seed_deg``/``seed_m``: how far off the seed may be (the
    lidar search region grows with them); ``use_edges``: the edge-to-outline residuals (the
    in-plane constraint); ``outlier_factor``: a frame whose plane or edge RMS exceeds this many
    times the median frame's (and twice the sensor noise) is left out. ``crop_margins_m``: how
    far beyond the board's outline each refinement's crop reaches (the last one for any further
    refinement): generous while the extrinsic is the first solve's, tight once it has been
    refined, so that a hand or the stand at the board's rim (coplanar within the lidar's noise)
    neither tilts the plane nor makes the rings' ends."""

    seed_deg: float = 6.0
    seed_m: float = 0.25
    use_edges: bool = True
    outlier_factor: float = 3.0
    leave_one_out: bool = True
    refinements: int = 2
    crop_margins_m: tuple[float, ...] = (0.05, 0.02)

    def margin(self, refinement: int) -> float:
        """The crop margin (m) of refinement ``refinement`` (0-based)."""
        return self.crop_margins_m[min(refinement, len(self.crop_margins_m) - 1)]

    def to_dict(self) -> dict:
        return {"seed_deg": self.seed_deg, "seed_m": self.seed_m, "use_edges": self.use_edges,
                "outlier_factor": self.outlier_factor, "plane_sigma_m": PLANE_SIGMA_M, "edge_sigma_m": EDGE_SIGMA_M,
                "crop_margins_m": list(self.crop_margins_m)}


@dataclass(frozen=True)
class FrameRecord:
    """One frame of a target calibration, for the table: the detection, the lidar board, the
    residuals at the result (m; NaN when not computed), whether it was used and why not
    (``reason``), and how far the result moves when it alone is left out (``loo_*``)."""

    name: str
    detection: Detection
    lidar: LidarBoard
    used: bool
    reason: str = ""
    plane_rms_m: float = float("nan")
    plane_mean_m: float = float("nan")
    edge_rms_m: float = float("nan")
    loo_m: float = float("nan")
    loo_deg: float = float("nan")

    @property
    def detected(self) -> bool:
        return self.detection.found

    def to_dict(self) -> dict:
        f = lambda v, k=6: None if not np.isfinite(v) else round(float(v), k)  # noqa: E731
        return {"name": self.name, "detected": self.detected, "detector": self.detection.method or None,
                "reprojection_px": f(self.detection.reprojection_px, 4), "lidar_points": self.lidar.n_points,
                "edge_points": 0 if self.lidar.edges is None else int(len(self.lidar.edges)),
                "plane_rms_m": f(self.plane_rms_m), "plane_mean_m": f(self.plane_mean_m),
                "edge_rms_m": f(self.edge_rms_m), "used": self.used, "reason": self.reason or None,
                "leave_out_moves_m": f(self.loo_m), "leave_out_moves_deg": f(self.loo_deg, 4)}


@dataclass(frozen=True)
class TargetDetail:
    """What a target calibration adds to its :class:`CalibrationResult` (``result.target``)."""

    board: Board
    frames: tuple[FrameRecord, ...]
    sigma_m: np.ndarray  # (3,) per-axis standard deviation of the translation (camera frame)
    sigma_deg: np.ndarray  # (3,) of the rotation about camera x, y, z
    observability: Observability
    settings: TargetSettings = field(default_factory=TargetSettings)
    seconds: dict = field(default_factory=dict)  # detection / lidar / solve wall times

    @property
    def used(self) -> list[FrameRecord]:
        return [f for f in self.frames if f.used]

    @property
    def detection_rate(self) -> float:
        return sum(f.detected for f in self.frames) / max(len(self.frames), 1)

    def plane_rms_m(self) -> float:
        """RMS point-to-plane distance of all used frames' points at the result (m)."""
        num = sum(f.plane_rms_m**2 * f.lidar.n_points for f in self.used)
        den = sum(f.lidar.n_points for f in self.used)
        return float(np.sqrt(num / den)) if den else float("nan")

    def edge_rms_m(self) -> float:
        vals = [f.edge_rms_m for f in self.used if np.isfinite(f.edge_rms_m)]
        return float(np.sqrt(np.mean(np.square(vals)))) if vals else float("nan")

    def to_dict(self) -> dict:
        return {
            "method": "checkerboard",
            "board": self.board.to_dict(),
            "frames_detected": int(sum(f.detected for f in self.frames)),
            "frames_used": len(self.used),
            "frames_total": len(self.frames),
            "sigma": {"x_m": float(self.sigma_m[0]), "y_m": float(self.sigma_m[1]), "z_m": float(self.sigma_m[2]),
                      "rx_deg": float(self.sigma_deg[0]), "ry_deg": float(self.sigma_deg[1]),
                      "rz_deg": float(self.sigma_deg[2])},
            "plane_rms_m": round(self.plane_rms_m(), 6),
            "edge_rms_m": None if not np.isfinite(self.edge_rms_m()) else round(self.edge_rms_m(), 6),
            "observability": self.observability.to_dict(),
            "settings": self.settings.to_dict(),
            "seconds": {k: round(v, 3) for k, v in self.seconds.items()},
            "frames": [f.to_dict() for f in self.frames],
        }


def scan_rings(scene: Scene) -> np.ndarray | None:
    """The ring number of each of ``scene.points`` from its file's ring field, or None (cached
    beside the parsed scans in the user's cache folder, keyed by the file's path, size and time)."""
    path = scene.lidar_path
    if path is None or not path.is_file():
        return None
    st = path.stat()
    key = hashlib.sha1(os.fsencode(path.resolve()) + f"|{st.st_size}|{st.st_mtime_ns}".encode()).hexdigest()[:16]
    cached = user_cache_dir("rings") / f"{key}.npy"
    try:
        rings = np.load(cached)
        return rings if rings.size == len(scene.points) else None
    except (OSError, ValueError):
        pass
    try:
        scan = load_lidar(path)
    except InputError:
        return None
    rings = scan.ring if scan.ring is not None and len(scan.ring) == len(scene.points) else None
    buf = io.BytesIO()
    np.save(buf, np.zeros(0, np.int32) if rings is None else rings.astype(np.int32))
    try:
        atomic_write_bytes(cached, buf.getvalue())
    except OSError:
        pass
    return rings


def detect_frames(scenes: Sequence[Scene], camera: CameraModel, board: Board, use_cache: bool = True,
                  on_frame: Callable[[int, int, str], None] | None = None,
                  cancel: threading.Event | None = None) -> list[Detection]:
    """The board in every scene's image (``scene.event_map``), cached; ``on_frame(i, n, name)`` before each."""
    out = []
    for i, sc in enumerate(scenes):
        if cancel is not None and cancel.is_set():
            break
        if on_frame:
            on_frame(i, len(scenes), sc.name)
        out.append(detect_cached(sc.event_map, board, camera, sc.name, use_cache))
    return out


def calibrate_target(
    scenes: Sequence[Scene],
    camera: CameraModel,
    seed: Extrinsic,
    board: Board,
    settings: TargetSettings = TargetSettings(),
    exclude: Collection[str] = (),
    on_progress: Callable[[Progress], None] | None = None,
    cancel: threading.Event | None = None,
    use_cache: bool = True,
    detections: Sequence[Detection] | None = None,
) -> CalibrationResult:
    """Calibrate from the board seen in ``scenes`` (see the module docstring).

    ``on_progress`` gets a :class:`l2e_studio.calibrate.Progress` per step (stage 1 detection,
    2 lidar boards, 3 solve; ``mi``/``best_mi`` carry minus the RMS point-to-plane distance in
    mm once there is one); ``cancel`` stops it between steps and hands back the best so far (the
    seed before the first solve). ``detections`` (from :func:`detect_frames`) skips detection.
    Raises :class:`InputError` when fewer than 3 frames have a board in both sensors."""
    t0 = time.perf_counter()
    excluded = set(exclude)
    tick = _Ticker(on_progress, t0, seed)
    if detections is None:
        detections = detect_frames(scenes, camera, board, use_cache, lambda i, n, _: tick(0, i / n), cancel)
    t_det = time.perf_counter()
    rings = {}
    boards: dict[str, LidarBoard] = {}
    for i, (sc, det) in enumerate(zip(scenes, detections)):
        if _cancelled(cancel):
            break
        tick(1, i / len(scenes))
        if det.found and sc.name not in excluded:
            rings[sc.name] = scan_rings(sc)
            boards[sc.name] = search_board(sc.points, rings[sc.name], det, board, seed, settings.seed_deg, settings.seed_m)
    t_lidar = time.perf_counter()
    by_name = {sc.name: (sc, det) for sc, det in zip(scenes, detections)}
    found = [n for n, b in boards.items() if b.found]
    if len(found) < MIN_FRAMES and not _cancelled(cancel):
        lines = [f"{d.name}: {d.reason}" for d in detections if not d.found][:3]
        lines += [f"{n}: lidar: {b.reason}" for n, b in boards.items() if not b.found][:3]
        raise InputError(None, f"the board was found in both sensors in {len(found)} of {len(scenes)} frames "
                               f"(at least {MIN_FRAMES} are needed)" + ("; " + "; ".join(lines) if lines else ""))

    def frames_of(names):
        return [TargetFrame(n, by_name[n][1].pose, boards[n].points, boards[n].edges,
                            boards[n].azimuth_step_rad) for n in names]

    current, sol, left_out = seed, None, {}
    if not _cancelled(cancel):
        frames = frames_of(found)
        sol = solve(frames, board, closed_form(frames, seed), settings.use_edges, covariance=False)
        current = sol.extrinsic
        tick(2, 0.3, current, frames, board)
        cropped = None
        for k in range(settings.refinements + SETTLE_CROPS):
            if _cancelled(cancel):
                break
            for n in boards:
                sc, det = by_name[n]
                boards[n] = crop_board(sc.points, rings[n], det, board, current, settings.margin(k))
            # past the scheduled refinements, crop again until the crops hold the same points: a
            # point on the tight crop's rim must not decide the answer by where the seed led
            before, cropped = cropped, [b.indices.tobytes() if b.found else b"" for b in boards.values()]
            if k >= settings.refinements and cropped == before:
                break
            usable = [n for n, b in boards.items() if b.found]
            left_out = _disagreeing(current, frames_of(usable), board, settings)
            use = [n for n in usable if n not in left_out]
            if len(use) < MIN_FRAMES:
                break
            sol = solve(frames_of(use), board, current, settings.use_edges, covariance=False)
            current = sol.extrinsic
            tick(2, 0.6, current, frames_of(use), board)
    used = [n for n, b in boards.items() if b.found and n not in left_out]
    final_frames = frames_of(used)
    if sol is not None and not _cancelled(cancel):
        sol = solve(final_frames, board, current, settings.use_edges, covariance=True,
                    also_from=[closed_form(final_frames, current)])
        current = sol.extrinsic
    loo = _leave_one_out(final_frames, board, current, settings) if (
        settings.leave_one_out and sol is not None and not _cancelled(cancel)) else {}
    t_solve = time.perf_counter()
    tick(2, 1.0, current, final_frames, board)

    records = []
    for sc, det in zip(scenes, detections):
        lb = boards.get(sc.name, LidarBoard(False, "left out by the user" if sc.name in excluded and det.found
                                            else ("no board in the image" if not det.found else "not searched (cancelled)")))
        reason = ("left out by the user" if sc.name in excluded else
                  f"no board in the image: {det.reason}" if not det.found else
                  f"no board in the lidar scan: {lb.reason}" if not lb.found else left_out.get(sc.name, ""))
        res = None
        if lb.found and det.found:
            res = frame_residuals(current, TargetFrame(sc.name, det.pose, lb.points, lb.edges), board)
        moved = loo.get(sc.name, (np.nan, np.nan))
        records.append(FrameRecord(sc.name, det, lb, sc.name in used, reason,
                                   *(np.nan,) * 3 if res is None else (res.plane_rms_m, res.plane_mean_m, res.edge_rms_m),
                                   moved[0], moved[1]))
    nan3 = np.full(3, np.nan)
    detail = TargetDetail(board, tuple(records), nan3 if sol is None else sol.sigma_m,
                          nan3 if sol is None else sol.sigma_deg, observability(final_frames), settings,
                          {"detection": t_det - t0, "lidar": t_lidar - t_det, "solve": t_solve - t_lidar})
    used_by = {f.name: f for f in final_frames}
    per_seed, per_res = (np.array([_score([used_by[sc.name]], board, e) if sc.name in used_by else np.nan
                                   for sc in scenes]) for e in (seed, current))
    return CalibrationResult(
        extrinsic=current, seed=seed, settings=CalibrationSettings(), scene_names=[sc.name for sc in scenes],
        score_seed=_score(final_frames, board, seed), score_result=_score(final_frames, board, current),
        score_seed_per_scene=per_seed, score_result_per_scene=per_res,
        evaluations=0 if sol is None else sol.evaluations, seconds=time.perf_counter() - t0,
        cancelled=_cancelled(cancel), message="cancelled" if _cancelled(cancel) else (sol.message if sol else ""),
        objective=OBJECTIVE, method="target", target=detail,
    )


def _score(frames: list[TargetFrame], board: Board, ext: Extrinsic) -> float:
    """Minus the RMS point-to-plane distance (mm) of ``frames`` at ``ext`` (higher is better, as every score)."""
    if not frames:
        return float("nan")
    r = np.concatenate([residuals_at(ext, f, board)[0] for f in frames])
    return -1000.0 * float(np.sqrt(np.mean(r**2)))


def _disagreeing(ext: Extrinsic, frames: list[TargetFrame], board: Board, settings: TargetSettings) -> dict[str, str]:
    """Frames whose plane or edge RMS at ``ext`` exceeds ``outlier_factor`` x the median frame's
    (and twice the sensor noise): {name: reason}."""
    if len(frames) < MIN_FRAMES + 1:
        return {}
    res = {f.name: frame_residuals(ext, f, board) for f in frames}
    plane_med = float(np.median([r.plane_rms_m for r in res.values()]))
    edges = [r.edge_rms_m for r in res.values() if np.isfinite(r.edge_rms_m)]
    edge_med = float(np.median(edges)) if edges else np.inf
    out = {}
    for n, r in res.items():
        lim_p = max(settings.outlier_factor * plane_med, 2 * PLANE_SIGMA_M)
        lim_e = max(settings.outlier_factor * edge_med, 2 * EDGE_SIGMA_M)
        if r.plane_rms_m > lim_p:
            out[n] = (f"disagrees with the other frames: its lidar points lie {100 * r.plane_rms_m:.1f} cm RMS off the "
                      f"camera's board plane (limit {100 * lim_p:.1f} cm)")
        elif settings.use_edges and np.isfinite(r.edge_rms_m) and r.edge_rms_m > lim_e:
            out[n] = (f"disagrees with the other frames: its edge points lie {100 * r.edge_rms_m:.1f} cm RMS off the "
                      f"board's outline (limit {100 * lim_e:.1f} cm)")
    return out


def _leave_one_out(frames: list[TargetFrame], board: Board, ext: Extrinsic,
                   settings: TargetSettings) -> dict[str, tuple[float, float]]:
    """{name: (metres, degrees) the result moves when that frame alone is left out}."""
    if len(frames) <= MIN_FRAMES:
        return {}
    return {f.name: moved for f, moved in zip(frames, leave_one_out(ext, frames, board, settings.use_edges))}


def _cancelled(cancel: threading.Event | None) -> bool:
    return cancel is not None and cancel.is_set()


class _Ticker:
    """Sends :class:`Progress` snapshots: 3 stages, the best extrinsic so far, minus the RMS (mm)."""

    def __init__(self, on_progress, t0: float, seed: Extrinsic) -> None:
        self.on_progress, self.t0, self.best, self.count, self.value = on_progress, t0, seed, 0, float("nan")

    def __call__(self, stage: int, done: float, best: Extrinsic | None = None, frames=None, board=None) -> None:
        self.count += 1
        if best is not None:
            self.best = best
            if frames:
                self.value = _score(frames, board, best)
        if self.on_progress is not None:
            self.on_progress(Progress(self.count, stage, 3, self.value, self.value, self.best,
                                      (stage + min(max(done, 0.0), 1.0)) / 3, time.perf_counter() - self.t0))
