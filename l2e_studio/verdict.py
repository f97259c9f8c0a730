"""Is a calibration result to be trusted? Evidence the optimiser did not climb, and a decision.

A score's maximum is only as good as the score, and on real recordings a score can peak degrees
from the truth. So the result is judged by what the optimiser never saw or never maximised:

* **halves**: the scenes are split in two (a single scene: its points left and right of the image
  centre). Each half on its own must score the result above the seed (the optimiser only saw
  their sum), and the result must be a peak of each half: refined on one half alone, it stays.
* **an independent second score**: for camera images, the share of lidar edge points that land
  within a few pixels of a Canny edge (binary edges, no smoothing, no band-pass: not what the
  edge objective climbs); for event maps, the paper's MI on the raw maps.
* **a second start**: the seed mirrored through the result; calibrated from there, it must come
  back to the result (a side peak reached from the seed seldom attracts both sides).
* **translation observable**: moving the result 5 cm along each axis must cost the score a fair
  share; a flat axis (forward, on one street scan) is not pinned down, whatever the optimiser says.
* **the result's own score** must beat the seed's.
* **a significant peak**: the score at the result against its own random fluctuations around it
  (the score at random rotations 2-8 deg away, its steady trend with the distance taken out). Halves, second starts and the second score all
  agree when every scene shares one bias (a static rig records one background many times), but a
  landscape at noise level puts its highest point wherever the noise does: the result's height
  above that far field, in standard deviations, must exceed what the best of noise reaches over
  the searched box (:func:`l2e_studio.peaks.noise_ceiling`).

Per translation axis the verdict says whether the scenes pin it, and what to record when not
(:func:`translation_axes`).

All agree: ``trusted``. Only the translation checks fail (one or two street scans seldom pin the
translation): ``trusted-rotation``, the checked rotation with the seed's translation (the result's
along the axes the scenes pin, when the halves and the second start agree on it), if the scenes
and both halves prefer that to the seed; when the rotation's checks failed too, a rotation fitted
to the seed's translation gets a second chance on the same evidence. Otherwise ``not-trusted``:
the seed is handed back (the default) or the result is kept and marked, as the caller chooses;
each failed check gives one line of why.

A trusted result is handed back only as far as it moved significantly: where the rotation turned,
or the translation moved along an axis, by less than twice the spread of the independent
estimates (the halves refined alone, the second start), the seed's stands (:func:`settle`), and
the verdict says so. A seed already at the peak is confirmed, not nudged by the estimate's scatter.
"""

from __future__ import annotations

import functools
import threading
import time
from concurrent.futures import ThreadPoolExecutor, wait
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from .calibrate import CalibrationResult, CalibrationSettings, Progress, refine
from .camera import CameraModel
from .verdict_check import Check
from .geometry import Extrinsic
from .objective import SceneStack, single_threaded_blas
from .peaks import far_climbs, rival_check, significance_check
from .scoring.edges import canny_distance, lidar_edge_weights

STATUSES = ("trusted", "trusted-rotation", "not-trusted")
ON_UNTRUSTED = ("keep-seed", "mark")
AGREE_DEG = 0.3  # independent answers must agree this well (at least) ...
AGREE_M = 0.03  # ... in rotation and in translation
AGREE_FRACTION = 0.5  # ... and in rotation to within this share of the distance the result moved from the seed,
AGREE_MAX_DEG = 0.6  # ... but never looser than this (a far move is no licence for a loose answer)
PROBE_M = 0.05  # translation probes: the score must drop when the result moves this far along each axis ...
#: ... by at least this share of its value, or that axis is not pinned down. Per objective: the
#: edge score is zero-mean by construction (band-passed map), so its relative changes read
#: directly; the MI carries a large pose-independent part (the marginal entropies), which
#: compresses them (synthetic scenes whose translation is recovered to 2 mm lose 5 % over 5 cm).
OBSERVABLE_DROP = {"edges": 0.1, "mi": 0.02}
EDGE_RADIUS_PX = 3.0  # an edge point "lands on" a Canny edge within this distance (at 1280 px wide)
SECOND_SCORE_SLACK = 0.005  # the second score may not drop by more than this (share of edge weight)
MIRROR_DEG, MIRROR_M = 1.0, 0.05  # the second start is at least this far from the result
REFIT_BOUND_DEG = 1.0  # rotation re-fitted to the seed's translation stays this close to the checked one
#: A move from the seed is handed back only where it exceeds this many times the spread of the
#: independent estimates (each half refined alone, the second start): a smaller move cannot be
#: told from the estimate's own scatter, and the seed stands (a released calibration checked
#: again is confirmed, not nudged by noise).
SIGNIFICANT = 2.0
#: Per camera axis: what moves its translation, and what to record when the scenes do not pin it.
AXIS_ADVICE = {
    "x": "add scenes with near objects (a few metres) whose vertical edges stand in front of a far background",
    "y": "add scenes with near objects whose top or bottom edges are in view (a table, a car's roof at a few metres)",
    "z": "add scenes with near objects at the image's left and right edges",
}


@dataclass(frozen=True)
class Verdict:
    """The decision on one result: ``status``, the extrinsic handed back, and why."""

    status: str
    extrinsic: Extrinsic
    kept_seed: bool
    reasons: tuple[str, ...]  # one line per failed check (empty when trusted)
    checks: tuple[Check, ...]
    seconds: float
    #: per camera axis (x right, y down, z forward): is the translation pinned, and if not what to record
    translation: tuple["AxisPinned", ...] = ()
    #: the axes whose translation is the seed's in what is handed back (``trusted-rotation``)
    seed_axes: str = "xyz"
    #: how far independent estimates landed from the result (see :class:`Spread`); None: not measured
    spread: "Spread | None" = None
    #: What of the seed stands although the result is trusted, because the result's move from it
    #: was within SIGNIFICANT x its spread: the rotation, and translation axes (beyond ``seed_axes``)
    seed_rotation: bool = False
    settled_axes: str = ""
    settled: str = ""  # that, in one sentence ("" when nothing)

    def __post_init__(self) -> None:
        if self.status not in STATUSES:
            raise ValueError(f"status must be one of {', '.join(STATUSES)}")

    @property
    def trusted(self) -> bool:
        return self.status != "not-trusted"

    @property
    def seed_stands(self) -> bool:
        """What is handed back is the seed itself, confirmed: the result is within its own spread of it."""
        return self.trusted and self.seed_rotation and set(self.seed_axes + self.settled_axes) >= set("xyz")

    def summary(self) -> str:
        """One line a user understands (the reasons are in ``reasons``)."""
        if self.seed_stands:
            unpinned = "" if self.status == "trusted" else "; the scenes do not pin its translation" + (
                "" if set(self.seed_axes) >= set("xyz") else " along " + ", ".join(self.seed_axes)) + " down"
            return "the seed stands, confirmed: " + self.settled + unpinned
        line = self._summary()
        return f"{line}; {self.settled}" if self.settled else line

    def _summary(self) -> str:
        if self.status == "trusted":
            return "trusted: both halves of the data, a second start and an independent score agree with the result"
        taken = ", ".join(a for a in "xyz" if a not in self.seed_axes + self.settled_axes)  # the result's
        if self.status == "trusted-rotation" and taken:
            kept = ", ".join(self.seed_axes)
            return (f"rotation and the translation along {taken} trusted; along {kept} the translation is not "
                    f"pinned down by these scenes, the seed's is kept")
        if self.status == "trusted-rotation" and self.seed_axes != "xyz":
            return (f"rotation trusted; along {', '.join(self.seed_axes)} the translation is not pinned down by "
                    f"these scenes, the seed's is kept")
        if self.status == "trusted-rotation":
            return "rotation trusted; the translation is not pinned down by these scenes, the seed's translation is kept"
        return "not trusted: " + ("the seed is kept" if self.kept_seed else "the result is kept, marked not trusted")

    def from_seed(self) -> list[str]:
        """What of the seed is in what is handed back although the verdict trusts the result (the
        rotation, the translation or some of its axes), in words; [] when none is."""
        if not self.trusted:
            return []
        axes = "".join(a for a in "xyz" if a in self.settled_axes or (self.status == "trusted-rotation" and a in self.seed_axes))
        return ((["rotation"] if self.seed_rotation else [])
                + (["translation"] if axes == "xyz" else [f"translation along {', '.join(axes)}"] if axes else []))

    def advice(self) -> list[str]:
        """One line per translation axis the scenes do not pin: which, and what to record."""
        return [a.line() for a in self.translation if not a.pinned]

    def lines(self) -> list[str]:
        """The summary, one indented line per reason, then what to record (for a terminal)."""
        return ([f"verdict: {self.summary()}"] + [f"  - {r}" for r in self.reasons]
                + [f"  > {a}" for a in self.advice()])

    def to_dict(self) -> dict:
        return {
            "status": self.status,
            "summary": self.summary(),
            "kept_seed": self.kept_seed,
            **({"translation_from_seed": list(self.seed_axes)} if self.status == "trusted-rotation" else {}),
            **({"within_spread": {"rotation_from_seed": self.seed_rotation, "translation_from_seed": list(self.settled_axes),
                                  "note": self.settled}} if self.settled else {}),
            **({"spread": self.spread.to_dict()} if self.spread is not None else {}),
            **({"seed_stands": True} if self.seed_stands else {}),
            "reasons": list(self.reasons),
            "checks": {c.name: {"passed": c.passed, "detail": c.detail} for c in self.checks},
            "translation_axes": {a.axis: {"pinned": a.pinned, "score_drop": round(a.drop, 4),
                                          **({} if a.pinned else {"advice": a.line()})} for a in self.translation},
            "seconds": round(self.seconds, 3),
        }


@dataclass(frozen=True)
class JudgeProgress:
    """A snapshot sent to ``judge``'s ``on_progress``: step ``step`` of ``steps`` (1-based; the
    count grows when a rotation is re-fitted), what it is, and the share of the judging done."""

    step: int
    steps: int
    label: str
    fraction: float  # 0..1 (within a refinement, its optimiser's own progress)
    elapsed: float  # seconds


class JudgingCancelled(RuntimeError):
    """Raised by :func:`judge` once its ``cancel`` event is set: a half-judged result has no verdict."""


class _Steps:
    """The judging's steps: a cancel check and a progress report at each (and inside refinements)."""

    def __init__(self, total: int, cancel: threading.Event | None, on_progress: Callable[[JudgeProgress], None] | None):
        self.step, self.total, self.label = 0, total, ""
        self.cancel, self.on_progress, self.t0 = cancel, on_progress, time.perf_counter()

    def check(self) -> None:
        if self.cancel is not None and self.cancel.is_set():
            raise JudgingCancelled("judging cancelled")

    def next(self, label: str) -> None:
        """Step ``label`` begins (raises :class:`JudgingCancelled` when cancelled)."""
        self.check()
        self.step, self.label = self.step + 1, label
        self.total = max(self.total, self.step)
        self._report(0.0)

    def within(self, p: Progress) -> None:
        """A refinement's progress (the ``on_progress`` of :func:`l2e_studio.calibrate.refine`)."""
        self._report(p.fraction)

    def _report(self, inner: float) -> None:
        if self.on_progress is not None:
            self.on_progress(JudgeProgress(self.step, self.total, self.label,
                                           min(1.0, (self.step - 1 + inner) / self.total), time.perf_counter() - self.t0))


@dataclass(frozen=True)
class Spread:
    """How far the independent estimates of a result landed from it (the largest of: each half of
    the data refined alone, the second start): its rotation in degrees, its translation in metres
    (nan where only the rotation was estimated)."""

    deg: float
    m: float = float("nan")

    def to_dict(self) -> dict:
        return {"rotation_deg": round(self.deg, 4), **({} if np.isnan(self.m) else {"translation_m": round(self.m, 4)})}


def settle(seed: Extrinsic, handed: Extrinsic, seed_axes: str, spread: Spread,
           sides: Callable[[], list[SceneStack]]) -> tuple[Extrinsic, bool, str, str]:
    """``handed`` with the seed's rotation, and the seed's translation along the axes outside
    ``seed_axes``, wherever its move from the seed is within SIGNIFICANT x ``spread``.
    Returns (extrinsic, rotation is the seed's, those translation axes, one sentence). A partial
    mix must still score above the seed on each of ``sides()`` (the data and its halves), else the
    seed stands whole: the significant part alone was not what the data preferred."""
    turn = seed.error_to(Extrinsic(handed.rotvec, seed.translation))[0]
    keep_rot = turn <= SIGNIFICANT * spread.deg
    moved = np.abs(handed.translation - seed.translation)
    mine = np.array([a not in seed_axes for a in "xyz"])  # the result's translation axes
    if np.array_equal(handed.matrix, seed.matrix):
        return seed, True, "".join(a for a, k in zip("xyz", mine) if k), "the optimiser ended at the seed itself"
    keep_t = mine & ~(moved > SIGNIFICANT * spread.m)  # (a spread of nan keeps only what did not move)
    shown_rot, shown_t = keep_rot and turn > 1e-9, keep_t & (moved > 1e-12)  # kept, and not the same anyway
    if not shown_rot and not shown_t.any():
        return handed, False, "", ""
    parts = []
    if shown_rot:
        parts.append(f"the seed's rotation stands (the result turned {turn:.2f} deg from it, within "
                     f"{SIGNIFICANT:g}x the {spread.deg:.2f} deg its independent estimates spread)")
    if shown_t.any():
        axes = ", ".join(a for a, k in zip("xyz", shown_t) if k)
        cm = "/".join(f"{100 * d:.1f}" for d, k in zip(moved, shown_t) if k)
        parts.append(f"the seed's translation along {axes} stands (the result moved {cm} cm, within "
                     f"{SIGNIFICANT:g}x the {100 * spread.m:.1f} cm its independent estimates spread)")
    out = Extrinsic(seed.rotvec if keep_rot else handed.rotvec, np.where(keep_t, seed.translation, handed.translation))
    if (not keep_rot or (mine & ~keep_t).any()) and not all(  # some of the move remains: it alone must beat the seed
            h.score(out, per_scene=False)[0] > h.score(seed, per_scene=False)[0] for h in sides()):
        parts.append("the rest of the move does not, alone, score above the seed on the data and both halves: "
                     "the seed stands whole")
        out, keep_rot, keep_t = seed, True, mine
    return out, bool(keep_rot), "".join(a for a, k in zip("xyz", keep_t) if k), "; ".join(parts)


@dataclass(frozen=True)
class AxisPinned:
    """Whether the scenes pin the translation along one camera axis: the share of the score lost
    by moving ``PROBE_M`` along it (the smaller side), against the objective's need."""

    axis: str  # "x", "y" or "z" (camera frame: right, down, forward)
    pinned: bool
    drop: float

    def line(self) -> str:
        state = "pinned" if self.pinned else "not pinned"
        text = f"{self.axis} is {state} (moving {100 * PROBE_M:.0f} cm costs {100 * self.drop:.0f} % of the score)"
        return text if self.pinned else f"{text}: {AXIS_ADVICE[self.axis]}"


def translation_axes(drops: np.ndarray, objective: str) -> tuple[AxisPinned, ...]:
    """Per camera axis, whether :func:`translation_drops` shows the scenes pin it."""
    need = OBSERVABLE_DROP[objective]
    return tuple(AxisPinned(axis, bool(d >= need), float(d)) for axis, d in zip("xyz", drops))


def halves(stack: SceneStack, at: Extrinsic) -> tuple[np.ndarray, np.ndarray]:
    """Two disjoint point masks: alternate scenes, or (one scene) left and right of the image centre at ``at``."""
    if stack.n_scenes >= 2:
        a = (stack.scene_of % 2) == 0
    else:
        uv, _ = stack.project(at)
        a = uv[:, 0] < stack.camera.width / 2.0
    return a, ~a


def mirrored_start(seed: Extrinsic, result: Extrinsic) -> Extrinsic:
    """The seed mirrored through the result (at least ``MIRROR_DEG`` / ``MIRROR_M`` from it): a
    second start on the far side, so a side peak reached from the seed is unlikely to attract it."""
    dt, dw = result.delta_to(seed)
    deg, m = np.degrees(np.linalg.norm(dw)), np.linalg.norm(dt)
    dw = dw * (MIRROR_DEG / deg) if deg < MIRROR_DEG and deg > 1e-9 else dw
    dt = dt * (MIRROR_M / m) if m < MIRROR_M and m > 1e-9 else dt
    if deg <= 1e-9:
        dw = np.radians(MIRROR_DEG) * np.array([1.0, 1.0, 1.0]) / np.sqrt(3.0)
    if m <= 1e-9:
        dt = MIRROR_M * np.array([1.0, -1.0, 1.0]) / np.sqrt(3.0)
    return result.perturbed(-dt, -dw)


def translation_drops(stack: SceneStack, res: Extrinsic, at_res: float) -> np.ndarray:
    """(3,) the share of the score lost by moving ``PROBE_M`` either way along x, y and z (the
    smaller of the two sides): a flat axis loses ~0, a pinned one a good part of its score."""
    drops = np.zeros(3)
    for k in range(3):
        step = np.zeros(3)
        step[k] = PROBE_M
        worst = max(stack.score(res.perturbed(sign * step, np.zeros(3)), per_scene=False)[0] for sign in (-1.0, 1.0))
        drops[k] = (at_res - worst) / abs(at_res) if at_res != 0 else 0.0
    return drops


def second_score(stack: SceneStack) -> tuple[str, Callable[[Extrinsic], float]]:
    """The independent score (its name, and the score as a function of the extrinsic): edge
    agreement for camera images, the paper's MI on the raw maps for event maps."""
    if all(k == "events" for k in stack.map_kinds):
        raw = stack.with_sigma(0.0)
        return "paper MI on the raw maps", lambda ext: raw.mi(ext, per_scene=False)[0]
    return "edge points on Canny edges", edge_agreement(stack)


def edge_agreement(stack: SceneStack) -> Callable[[Extrinsic], float]:
    """The weighted share of lidar edge points within ``EDGE_RADIUS_PX`` of a Canny edge of
    their map, as a function of the extrinsic (edges and distance maps computed once)."""
    weights = stack.weights
    if weights is None:
        weights = np.zeros(stack.n_points, dtype=np.float32)
        for s in range(stack.n_scenes):
            m = stack.scene_of == s
            weights[m] = lidar_edge_weights(stack.points[:, m].T, stack.l_bins[m].astype(np.float32))
    cam = stack.full_camera or stack.camera
    full = replace(stack, camera=cam)
    radius = EDGE_RADIUS_PX * cam.width / 1280.0
    distances = [canny_distance(raw) for raw in stack.raw_maps]
    total = float(weights.sum())

    def share(ext: Extrinsic) -> float:
        pix = full.pixels(ext)  # nearest pixel, -1 off the image
        near = np.zeros(stack.n_points, dtype=bool)
        for s, dist in enumerate(distances):
            m = (pix >= 0) & (stack.scene_of == s)
            near[m] = dist.reshape(-1)[pix[m]] <= radius
        return float(weights[near].sum() / total) if total > 0 else 0.0

    return share


def judge(
    stack: SceneStack,
    result: CalibrationResult,
    settings: CalibrationSettings = CalibrationSettings(),
    on_untrusted: str = "keep-seed",
    cancel: threading.Event | None = None,
    on_progress: Callable[[JudgeProgress], None] | None = None,
) -> Verdict:
    """Judge ``result`` (a calibration of ``stack`` from ``result.seed``) on evidence it did not climb.

    ``on_progress`` is called at each step (and within each refinement) with a
    :class:`JudgeProgress`; once ``cancel`` is set, the next check raises :class:`JudgingCancelled`
    (within one objective evaluation or one score, well under a second)."""
    if on_untrusted not in ON_UNTRUSTED:
        raise ValueError(f"on_untrusted must be one of {', '.join(ON_UNTRUSTED)}")
    t0 = time.perf_counter()
    # + translation probes, + climbs from the far field after a global search
    steps = _Steps(1 + evidence_steps(settings) + (not settings.rotation_only) + (len(result.ends) >= 2),
                   cancel, on_progress)
    seed, res = result.seed, result.extrinsic
    steps.next("preparing the final smoothing and the second score")
    final = stack.with_sigma(settings.sigma)
    steps.check()
    second = second_score(final)
    checks, spread = evidence(final, seed, res, settings, second, cancel, steps)
    axes: tuple[AxisPinned, ...] = ()
    if not settings.rotation_only:
        steps.next("translation probes: the result moved 5 cm along x, y, z")
        axes = translation_axes(translation_drops(final, res, final.score(res, per_scene=False)[0]), final.objective_name)
        need = OBSERVABLE_DROP[final.objective_name]
        checks.append(Check("translation observable (translation)", all(a.pinned for a in axes),
                            f"moving {100 * PROBE_M:.0f} cm along x, y, z lowers the score by "
                            + ", ".join(f"{100 * a.drop:.0f} %" for a in axes) + f" (at least {100 * need:.0f} % each)"))
    climbs: tuple = ()
    if len(result.ends) >= 2:  # a global search ran: climb from around the result too
        steps.next("climbs from the far field around the result")
        climbs = far_climbs(final, result, settings, cancel, steps.within)
    rival = rival_check(result, climbs)
    if rival is not None:
        checks.append(rival)
    failed = [c for c in checks if not c.passed]
    reasons = tuple(f"{c.name}: {c.detail}" for c in failed)
    sides = functools.cache(lambda: [final, *(final.select(m) for m in halves(final, seed))])  # the data, its halves: once

    def trusted(status: str, handed: Extrinsic, seed_axes: str, all_checks: tuple[Check, ...], spread: Spread) -> Verdict:
        out, seed_rot, settled_axes, settled = settle(seed, handed, seed_axes, spread, sides)
        return Verdict(status, out, False, reasons if status != "trusted" else (), all_checks,
                       time.perf_counter() - t0, axes, seed_axes, spread, seed_rot, settled_axes, settled)

    if not failed:
        return trusted("trusted", res, "", tuple(checks), spread)
    if all(c.name.endswith("(translation)") for c in failed):
        # Only the translation is not pinned down (one or two scans of a street seldom pin it):
        # hand back the checked rotation with the seed's translation, if the scenes and both
        # halves prefer that to the seed too.
        # Where halves and the second start agree on the translation, the axes the scenes pin
        # are the result's (the others the seed's); else all three are the seed's.
        agree = all(c.passed for c in checks if c.name in ("halves agree (translation)", "second start (translation)"))
        pinned = np.array([a.pinned for a in axes]) if agree and axes else np.zeros(3, dtype=bool)
        stacks = sides()
        for take in ([pinned, np.zeros(3, dtype=bool)] if pinned.any() else [pinned]):
            mixed = Extrinsic(res.rotvec, np.where(take, res.translation, seed.translation))
            if np.array_equal(mixed.matrix, seed.matrix) or all(  # (the optimiser ended at the seed: nothing to prefer)
                    h.score(mixed, per_scene=False)[0] > h.score(seed, per_scene=False)[0] for h in stacks):
                kept = "".join(a for a, t in zip("xyz", take) if not t)
                return trusted("trusted-rotation", mixed, kept, tuple(checks), spread)
    if any(c.name.endswith("(translation)") for c in failed) and not settings.rotation_only and \
            (rival is None or rival.passed):
        # A wrong translation also confounds the rotation's checks: keep the seed's translation,
        # fit the rotation to it (near the result's), and judge that rotation afresh.
        rotation = replace(settings, rotation_only=True)
        steps.total += 1 + evidence_steps(rotation)
        steps.next("re-fitting the rotation to the seed's translation")
        refit = refine(final, Extrinsic(res.rotvec, seed.translation),
                       replace(rotation, coarse_to_fine=False, global_search=False, rotation_bound_deg=REFIT_BOUND_DEG),
                       cancel, steps.within)
        refit = Extrinsic(refit.rotvec, seed.translation)
        rot_checks, rot_spread = evidence(final, seed, refit, rotation, second, cancel, steps)
        rot_failed = [c for c in rot_checks if not c.passed]
        if not rot_failed:
            return trusted("trusted-rotation", refit, "xyz", tuple(checks) + tuple(rot_checks), rot_spread)
        reasons += tuple(f"with the seed's translation, {c.name}: {c.detail}" for c in rot_failed)
        checks += rot_checks
    steps.check()
    keep = on_untrusted == "keep-seed"
    return Verdict("not-trusted", seed if keep else res, keep, reasons, tuple(checks), time.perf_counter() - t0, axes,
                   spread=spread)


def with_check(verdict: Verdict, check: Check, seed: Extrinsic, on_untrusted: str = "keep-seed") -> Verdict:
    """``verdict`` with one more piece of outside evidence (e.g. the boards in view,
    :func:`l2e_studio.target_verdict.board_check` of what the verdict hands back): a failed
    check makes a trusted result ``not-trusted``, the seed handed back (or the result marked)."""
    checks = verdict.checks + (check,)
    if check.passed or not verdict.trusted:
        return replace(verdict, checks=checks)
    keep = on_untrusted == "keep-seed"
    return replace(verdict, status="not-trusted", extrinsic=seed if keep else verdict.extrinsic, kept_seed=keep,
                   reasons=verdict.reasons + (f"{check.name}: {check.detail}",), checks=checks, seed_axes="xyz",
                   seed_rotation=False, settled_axes="", settled="")


def evidence_steps(settings: CalibrationSettings) -> int:
    """How many steps :func:`evidence` reports (scores, the peak's significance, two halves, second start)."""
    return 5


def evidence(
    final: SceneStack,
    seed: Extrinsic,
    res: Extrinsic,
    settings: CalibrationSettings,
    second: tuple[str, Callable[[Extrinsic], float]],
    cancel: threading.Event | None = None,
    steps: _Steps | None = None,
) -> tuple[list[Check], Spread]:
    """The checks of ``res`` against ``seed`` on ``final`` (the stack at the final smoothing),
    ``second`` being :func:`second_score` of it, and how far the independent estimates among
    them landed from ``res``. With ``settings.rotation_only`` the translation is the seed's and
    only the rotation is tested. ``steps``: progress and cancel (:func:`evidence_steps` of them)."""
    steps = steps or _Steps(evidence_steps(settings), cancel, None)
    # the second start is independent of the other checks: it climbs beside them, in a thread of
    # its own (on 2 cores, 40 full-size scenes: halves and second start 1.9 s one after the
    # other, 1.45 s side by side). BLAS stays on one thread for both: the nested limits of the
    # two climbs would otherwise restore each other's, and BLAS's thread count moves the last bit
    with single_threaded_blas(), ThreadPoolExecutor(1, thread_name_prefix="l2e-second-start") as pool:
        latest: list[Progress | None] = [None]
        second_start = pool.submit(refine, final, *_second_start(seed, res, settings, final.camera),
                                   cancel, lambda p: latest.__setitem__(0, p))
        checks, rot_moved, trans_moved = _checks_beside(final, seed, res, settings, second, cancel, steps)
        steps.next("a second start, mirrored through the result")
        while True:  # its progress shown from here on (it may well be done already)
            if latest[0] is not None:
                steps.within(latest[0])
            if wait([second_start], timeout=0.05).done:
                break
        other = second_start.result()
    steps.check()
    deg, m = other.error_to(res)
    limit_deg = agreement_limit(seed, res)
    tag = " (rotation only)" if settings.rotation_only else ""
    checks.append(Check("second start (rotation)" + tag, deg <= limit_deg,
                        f"from a start mirrored through the result it ends {deg:.3f} deg away (limit {limit_deg:.2f})"))
    if not settings.rotation_only:
        checks.append(Check("second start (translation)", m <= AGREE_M,
                            f"from a start mirrored through the result it ends {100 * m:.1f} cm away "
                            f"(limit {100 * AGREE_M:.0f})"))
    return checks, Spread(max(rot_moved + [deg]), float("nan") if settings.rotation_only else max(trans_moved + [m]))


def agreement_limit(seed: Extrinsic, res: Extrinsic) -> float:
    """How close (deg) independent estimates of ``res`` must come to it: well within the distance
    moved from ``seed`` (and to AGREE_DEG however small the move), never looser than AGREE_MAX_DEG."""
    return min(max(AGREE_DEG, AGREE_FRACTION * seed.error_to(res)[0]), AGREE_MAX_DEG)


def _second_start(seed: Extrinsic, res: Extrinsic, settings: CalibrationSettings, camera: CameraModel
                  ) -> tuple[Extrinsic, CalibrationSettings]:
    """Where the second start begins (the seed mirrored through the result; the result's
    translation when only the rotation is tested) and how it climbs: every stage on half its
    point budget (a probe, not the answer)."""
    start = mirrored_start(seed, res)
    if settings.rotation_only:
        start = Extrinsic(start.rotvec, res.translation)
    probe = replace(settings, stages=tuple(
        replace(st, max_points=None if st.max_points is None else st.max_points // 2)
        for st in settings.schedule(camera.width, camera.height)))
    return start, probe


def _checks_beside(final: SceneStack, seed: Extrinsic, res: Extrinsic, settings: CalibrationSettings,
                   second: tuple[str, Callable[[Extrinsic], float]], cancel: threading.Event | None, steps: _Steps
                   ) -> tuple[list[Check], list[float], list[float]]:
    """The checks of :func:`evidence` but the second start: scores, significance, halves; and how
    far each half refined alone moved the rotation (deg) and the translation (m)."""
    rotation_only = settings.rotation_only
    tag = " (rotation only)" if rotation_only else ""
    limit_deg = agreement_limit(seed, res)
    checks: list[Check] = []
    steps.next("the scores at the seed and at the result")
    # an optimiser that ends at the seed itself found nothing better: nothing to prefer (the
    # checks of the peak below still decide whether the seed is one)
    at_seed = bool(np.array_equal(res.matrix, seed.matrix))
    s_seed, s_res = final.score(seed, per_scene=False)[0], final.score(res, per_scene=False)[0]
    checks.append(Check("score" + tag, s_res > s_seed or at_seed, f"{final.objective_name} score {s_seed:.4f} -> {s_res:.4f}"
                        + (" (the optimiser ended at the seed)" if at_seed else "")))

    name, score2 = second
    steps.check()
    before, after = score2(seed), score2(res)
    slack = SECOND_SCORE_SLACK if name.startswith("edge") else 0.0
    checks.append(Check("second score" + tag, after >= before - slack, f"{name} {before:.4f} -> {after:.4f}"))

    steps.next("a significant peak: the score 2-8 deg around the result against its fluctuations")
    checks.append(significance_check(final, res, settings, tag))

    a, b = halves(final, seed)
    rot_moved: list[float] = []
    trans_moved: list[float] = []
    if a.sum() == 0 or b.sum() == 0:
        checks.append(Check("halves" + tag, False, "too few points to split into two halves"))
    else:
        # each half on its own must prefer the result to the seed, and the result must be a
        # peak of each half: refined on one half alone, it stays where it is
        last = settings.schedule(final.camera.width, final.camera.height)[-1]
        budget = None if last.max_points is None else last.max_points // 2  # half the points, half the budget
        local = replace(settings, stages=(replace(last, max_points=budget),), global_search=False)
        better, detail = True, []
        for i, mine in enumerate((a, b)):
            steps.next(f"half {i + 1} of 2: refined on its own")
            half = final.select(mine)
            h_seed, h_res = half.score(seed, per_scene=False)[0], half.score(res, per_scene=False)[0]
            better &= h_res > h_seed or at_seed
            detail.append(f"{h_seed:.4f} -> {h_res:.4f}")
            deg, m = refine(half, res, local, cancel, steps.within).error_to(res)
            if not rotation_only:
                trans_moved.append(m)
                if m > AGREE_M:  # a drifting translation confounds the rotation: ask for it alone
                    deg = refine(half, res, replace(local, rotation_only=True), cancel, steps.within).error_to(res)[0]
            rot_moved.append(deg)
        checks.append(Check("both halves prefer the result" + tag, better,
                            "score of each half, seed -> result: " + ", ".join(detail)))
        checks.append(Check("halves agree (rotation)" + tag, max(rot_moved) <= limit_deg,
                            f"refined on either half alone the rotation moves {max(rot_moved):.3f} deg "
                            f"(limit {limit_deg:.2f})"))
        if not rotation_only:
            checks.append(Check("halves agree (translation)", max(trans_moved) <= AGREE_M,
                                f"refined on either half alone the translation moves {100 * max(trans_moved):.1f} cm "
                                f"(limit {100 * AGREE_M:.0f})"))

    return checks, rot_moved, trans_moved
