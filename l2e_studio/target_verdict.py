"""The verdict on a checkerboard calibration, and the board as evidence on any calibration.

:func:`judge_target` turns a :func:`l2e_studio.target.calibrate_target` result into the same
:class:`l2e_studio.verdict.Verdict` every method gets. ``trusted`` only when all hold:

* **residuals consistent with the sensors' noise**: the board points' RMS distance to the
  camera's planes is within what the error model of the solve explains: the lidar's own scatter
  on each board (measured: its points about their own plane) and a per-frame offset of the whole
  board of ``FRAME_PLANE_M`` (the camera's depth of a board, the board's motion between image and
  scan), at the 99 % chi-square bound for the number of frames used (a few frames can sit further
  off by chance than many); the edge points' RMS distance to the outline within ``NOISE_EDGE_M``;
  the corners reproject within ``NOISE_REPROJECTION_PX``;
* **leave-one-frame-out stability**: no single frame moves the result by more than
  ``LOO_M`` / ``LOO_DEG`` when it alone is left out;
* **uncertainty within the limits**: on every axis the 95 % bound on the error (the reported
  sigma times Student's t for the used frames less one: the sigma is itself an estimate from a
  few frames) within ``ACCURACY_M`` / ``ACCURACY_DEG``; measured calibrated on synthetic boards
  (``benchmarks/bench_target.py --calibration``), so a result judged trusted is within these
  limits about 19 times in 20 per axis;
* **every axis pinned**: enough boards of different orientation (the board normals' RMS
  component along their weakest direction); when not, the check names the unobserved direction
  and the pose to add;
* at least ``MIN_USED`` frames used.

Otherwise ``not-trusted`` (the seed is handed back unless the caller asks to keep the result).
:func:`with_boards` judges ANY calibration (e.g. a targetless result) against the boards in
view: this method run from what its verdict hands back, the two compared by :func:`board_check`.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np

from .calibrate import CalibrationResult
from .camera import CameraModel
from .errors import InputError
from .geometry import Extrinsic
from .scenes import Scene
from .target import Board, Detection, TargetSettings, calibrate_target
from .target.solve import FRAME_PLANE_M
from .verdict import ON_UNTRUSTED, Check, Verdict, with_check

NOISE_EDGE_M = 0.03  # RMS edge-to-outline: azimuth step, beam width, mixed returns
NOISE_REPROJECTION_PX = 1.0  # RMS corner reprojection (px)
LOO_M, LOO_DEG = 0.01, 0.2  # the most one frame may move the result
ACCURACY_M, ACCURACY_DEG = 0.02, 0.5  # per axis, the most the 95 % error bound may be (the issue asks 3 cm / 0.5 deg of a reference)
MIN_USED = 6
MIN_BOARD_IMAGES = 3  # boards in fewer images are no evidence either way
BOARD_CHECK_DEG, BOARD_CHECK_M = 0.5, 0.03  # the least disagreement with the boards' own solution that fails a result
BOARD_SIGMAS = 3.76  # sqrt of the chi-square(3 dof) 99.7 % quantile: a disagreement past it is not the boards' noise
BOARD_AWAY_SIGMAS = 1.0  # a result further from the boards than its seed by more than this (in their sigmas) moved away from them
BOARDS_ALONE = TargetSettings(leave_one_out=False)  # the target method as evidence: no leave-one-out needed
BOARD_LOOSE_DEG = 3.0  # boards whose own rotation is looser (3 sigma, about every axis) than this cannot tell
NOISE_QUANTILE = 0.99  # the residuals' bound under the error model: their chi-square quantile


class TargetVerdict(Verdict):
    """A :class:`Verdict` whose summary speaks of boards (same fields, same type)."""

    def summary(self) -> str:
        if self.status == "trusted":
            return ("trusted: board residuals within the sensors' noise, stable when any frame is left out, "
                    "uncertainty within the limits, every axis pinned by the board orientations")
        return "not trusted: " + ("the seed is kept" if self.kept_seed else "the result is kept, marked not trusted")


def judge_target(result: CalibrationResult, on_untrusted: str = "keep-seed") -> Verdict:
    """Judge a target calibration (``result.target`` must be set) on the checks in the module docstring."""
    if on_untrusted not in ON_UNTRUSTED:
        raise ValueError(f"on_untrusted must be one of {', '.join(ON_UNTRUSTED)}")
    detail = result.target
    if detail is None:
        raise ValueError("not a target calibration (result.target is None)")
    t0 = time.perf_counter()
    used = detail.used
    checks = [Check("frames used", len(used) >= MIN_USED,
                    f"{len(used)} of {len(detail.frames)} frames used (at least {MIN_USED})")]
    plane, edge = detail.plane_rms_m(), detail.edge_rms_m()
    plane_limit, scatter = plane_bound(used)
    reps = [f.detection.reprojection_px for f in used]
    rep = float(np.sqrt(np.mean(np.square(reps)))) if reps else float("nan")
    rep_limit = NOISE_REPROJECTION_PX
    ok = bool(plane <= plane_limit and (not np.isfinite(edge) or edge <= NOISE_EDGE_M) and rep <= rep_limit)
    checks.append(Check("residuals within sensor noise", ok,
                        f"board points {100 * plane:.1f} cm RMS off the camera's planes (limit {100 * plane_limit:.1f}: "
                        f"the lidar's {100 * scatter:.1f} cm scatter on the boards and {100 * FRAME_PLANE_M:.0f} cm per board "
                        f"over {len(used)} frames, {100 * NOISE_QUANTILE:.0f} % bound), "
                        f"edge points {100 * edge:.1f} cm off the outline (limit {100 * NOISE_EDGE_M:.0f}), "
                        f"corners reproject {rep:.2f} px RMS (limit {rep_limit:.1f})"))
    loo = [(f.loo_m, f.loo_deg, f.name) for f in used if np.isfinite(f.loo_m)]
    if loo:
        worst_m = max(loo)
        worst_deg = max(loo, key=lambda x: x[1])
        checks.append(Check("leave one frame out", worst_m[0] <= LOO_M and worst_deg[1] <= LOO_DEG,
                            f"leaving one frame out moves the result at most {1000 * worst_m[0]:.1f} mm "
                            f"({worst_m[2]}) and {worst_deg[1]:.3f} deg ({worst_deg[2]}) "
                            f"(limits {1000 * LOO_M:.0f} mm, {LOO_DEG:g} deg)"))
    else:
        checks.append(Check("leave one frame out", False, "not computed (too few frames, or switched off)"))
    checks.append(uncertainty_check(detail.sigma_m, detail.sigma_deg, len(used)))
    obs = detail.observability
    checks.append(Check("every axis pinned", obs.observed,
                        f"board normals vary by {np.degrees(np.arcsin(min(obs.spread, 1.0))):.1f} deg RMS along their "
                        f"weakest direction" + (f"; {obs.advice}" if obs.advice else "")))
    failed = [c for c in checks if not c.passed]
    reasons = tuple(f"{c.name}: {c.detail}" for c in failed)
    if not failed and not result.cancelled:
        return TargetVerdict("trusted", result.extrinsic, False, (), tuple(checks), time.perf_counter() - t0)
    if result.cancelled:
        reasons += ("the run was cancelled",)
    keep = on_untrusted == "keep-seed"
    return TargetVerdict("not-trusted", result.seed if keep else result.extrinsic, keep, reasons, tuple(checks),
                         time.perf_counter() - t0)


def plane_bound(used) -> tuple[float, float]:
    """(the most the used frames' board points may lie RMS off the camera's planes, the lidar's
    own RMS scatter on those boards), both in m. Under the solve's error model a frame's points
    are off by the lidar's scatter about the board (each frame's, measured) plus one offset of
    the whole board with standard deviation ``FRAME_PLANE_M``; the offsets' mean square over n
    frames is bounded by the chi-square quantile over n."""
    from scipy.stats import chi2

    n_pts = np.array([f.lidar.n_points for f in used], float)
    if not len(used) or n_pts.sum() == 0:
        return float("nan"), float("nan")
    scatter = float(np.sqrt(np.sum(n_pts * np.square([f.lidar.rms_m for f in used])) / n_pts.sum()))
    n = len(used)
    return float(np.sqrt(FRAME_PLANE_M**2 * chi2.ppf(NOISE_QUANTILE, n) / n + scatter**2)), scatter


def uncertainty_check(sigma_m: np.ndarray, sigma_deg: np.ndarray, n_frames: int) -> Check:
    """Whether the 95 % error bound per axis (``sigma`` times the t quantile for ``n_frames - 1``
    degrees of freedom) is within ``ACCURACY_M`` / ``ACCURACY_DEG``."""
    from scipy.stats import t as student_t

    q = float(student_t.ppf(0.975, max(n_frames - 1, 1)))  # 2.26 for 10 frames, 2.10 for 19
    bound_m, bound_deg = q * np.asarray(sigma_m, float), q * np.asarray(sigma_deg, float)
    ok = bool(np.all(np.isfinite(bound_m)) and np.all(np.isfinite(bound_deg))
              and np.all(bound_m <= ACCURACY_M) and np.all(bound_deg <= ACCURACY_DEG))
    dof = max(n_frames - 1, 1)
    return Check("uncertainty within limits", ok,
                 f"95 % error bound per axis (sigma x {q:.2f}, t with {dof} dof): x y z "
                 f"{' '.join(f'{1000 * b:.1f}' for b in bound_m)} mm, rx ry rz {' '.join(f'{b:.3f}' for b in bound_deg)} deg "
                 f"(limits {1000 * ACCURACY_M:.0f} mm, {ACCURACY_DEG:g} deg)")


def board_check(extrinsic: Extrinsic, boards: CalibrationResult, rotation_only: bool = False,
                seed: Extrinsic | None = None) -> Check | None:
    """Whether ``boards`` (the target method's own result on the same scenes) agrees with
    ``extrinsic`` (any calibration, e.g. a targetless result): its rotation and, unless
    ``rotation_only`` (a result whose translation is the seed's), its translation each within
    ``BOARD_CHECK_DEG`` / ``BOARD_CHECK_M`` or within ``BOARD_SIGMAS`` of the boards' own
    per-axis uncertainty (the 99.7 % bound of a 3-D normal). Evidence the targetless optimiser
    never climbed. None when the boards cannot tell: too few frames used, or their own
    rotation looser than ``BOARD_LOOSE_DEG`` about every axis.

    The floor is for the boards' own bias (their σ counts only their noise), which a ``seed``
    shares: a result past ``BOARD_SIGMAS`` that sits more than ``BOARD_AWAY_SIGMAS`` further
    from the boards than its seed moved away from independent evidence, and fails under the
    floor too."""
    detail = boards.target
    sd_m, sd_deg = np.asarray(detail.sigma_m, float), np.asarray(detail.sigma_deg, float)
    n = len(detail.used)
    if n < MIN_BOARD_IMAGES or boards.cancelled or not np.all(np.isfinite(np.r_[sd_m, sd_deg])) \
            or 3 * float(np.min(sd_deg)) > BOARD_LOOSE_DEG:
        return None

    def off(ext: Extrinsic) -> tuple[float, float, float, float]:
        """(deg, m, rotation sigmas, translation sigmas) of ``ext`` from the boards' solution."""
        dt, dw = boards.extrinsic.delta_to(ext)
        return (float(np.degrees(np.linalg.norm(dw))), float(np.linalg.norm(dt)),
                float(np.linalg.norm(np.degrees(dw) / np.maximum(sd_deg, 1e-9))),
                float(np.linalg.norm(dt / np.maximum(sd_m, 1e-12))))

    deg, m, k_rot, k_t = off(extrinsic)
    _, _, k_rot0, k_t0 = off(seed) if seed is not None else (0.0, 0.0, np.inf, np.inf)
    away_rot = k_rot > BOARD_SIGMAS and k_rot - k_rot0 > BOARD_AWAY_SIGMAS
    away_t = not rotation_only and k_t > BOARD_SIGMAS and k_t - k_t0 > BOARD_AWAY_SIGMAS
    rot_ok = (deg <= BOARD_CHECK_DEG or k_rot <= BOARD_SIGMAS) and not away_rot
    t_ok = rotation_only or ((m <= BOARD_CHECK_M or k_t <= BOARD_SIGMAS) and not away_t)
    moved = "" if rotation_only else f", its translation {100 * m:.1f} cm ({k_t:.1f} sigma)"
    away = ""
    if away_rot or away_t:
        away = "; further from them than the seed (" + ", ".join(
            [f"rotation {k_rot0:.1f} -> {k_rot:.1f} sigma"] * away_rot
            + [f"translation {k_t0:.1f} -> {k_t:.1f} sigma"] * away_t) + "): it moved away from the boards"
    return Check("boards agree", bool(rot_ok and t_ok),
                 f"the boards alone ({n} frames) put the rotation {deg:.2f} deg ({k_rot:.1f} sigma of "
                 f"theirs){moved} from the one handed back (limits {BOARD_CHECK_DEG:g} deg"
                 + ("" if rotation_only else f" / {100 * BOARD_CHECK_M:g} cm") + f" or {BOARD_SIGMAS:.1f} sigma)"
                 + away)


def with_boards(verdict: Verdict, seed: Extrinsic, scenes: Sequence[Scene], camera: CameraModel, board: Board,
                detections: Sequence[Detection] | None = None, on_untrusted: str = "keep-seed") -> Verdict:
    """``verdict`` on any calibration of ``scenes`` with the boards in view as more evidence:
    the target method run from what it hands back (``detections``, else detected, cached),
    and :func:`board_check` of the two (the rotation alone for ``trusted-rotation``).
    A verdict that is not trusted keeps its status, the check listed (how far what it hands
    back lies from the boards); boards that cannot tell leave the verdict as it is."""
    try:
        boards = calibrate_target(scenes, camera, verdict.extrinsic, board, BOARDS_ALONE, detections=detections)
    except InputError:  # the board in fewer than 3 frames of both sensors: nothing to tell
        return verdict
    check = board_check(verdict.extrinsic, boards, rotation_only=verdict.status == "trusted-rotation", seed=seed)
    return verdict if check is None else with_check(verdict, check, seed, on_untrusted)
