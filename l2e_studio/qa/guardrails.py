"""Guardrails: warnings a reviewer must see before shipping a calibration.

Each check returns :class:`Warning` items (a code and one line of text); an empty list means
nothing was found. They only look at numbers the other QA functions produce.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..calibrate import CalibrationSettings
from ..geometry import Extrinsic
from . import AXES
from .heldout import ScoreTable
from .studies import correction

MIN_POINTS = 2000  # points in the image per scene below which a scene says little
MIN_SCENES = 10  # fewer scenes than this: warn even without a wanted spread
ON_BOUND = 0.98  # a correction beyond this share of the bound "sits on the bound"


@dataclass(frozen=True)
class Warning:
    code: str
    message: str

    def to_dict(self) -> dict:
        return {"code": self.code, "message": self.message}


def held_out_below_seed(table: ScoreTable, result: str = "result", seed: str = "seed") -> list[Warning]:
    names = [c.name for c in table.candidates]
    if result not in names or seed not in names:
        return []
    i, j = names.index(result), names.index(seed)
    out = []
    group = "held out" if "held out" in table.pooled else "all"
    if table.pooled[group][i] < table.pooled[group][j]:
        out.append(Warning("held_out_below_seed",
                           f"{group} scenes score lower at the result ({table.pooled[group][i]:.4f}) than at the seed "
                           f"({table.pooled[group][j]:.4f}): the result does not generalise"))
    mask = table.held_out if table.held_out.any() else np.ones(len(table.scenes), bool)
    worse = [s for k, s in enumerate(table.scenes) if mask[k] and table.per_scene[i, k] < table.per_scene[j, k]]
    if worse:
        out.append(Warning("scenes_below_seed", f"{len(worse)} {'held-out ' if table.held_out.any() else ''}scene(s) score "
                           f"lower at the result than at the seed: {', '.join(worse[:8])}{' ...' if len(worse) > 8 else ''}"))
    return out


def on_bound(result: Extrinsic, seed: Extrinsic, settings: CalibrationSettings) -> list[Warning]:
    c = correction(seed, result)
    bound = np.array([1000 * settings.translation_bound] * 3 + [settings.rotation_bound_deg] * 3)
    hit = [f"{a} ({v:+.2f} of +-{b:g} {'mm' if k < 3 else 'deg'})" for k, (a, v, b) in enumerate(zip(AXES, c, bound))
           if b > 0 and abs(v) >= ON_BOUND * b and not (settings.rotation_only and k < 3)]
    if not hit:
        return []
    return [Warning("on_bound", "the result sits on the search bound along " + ", ".join(hit)
                    + ": the optimum may lie outside; widen the bounds or improve the seed")]


def few_points(scenes: list[str], points_in_image: np.ndarray, min_points: int = MIN_POINTS) -> list[Warning]:
    low = [f"{s} ({int(n)})" for s, n in zip(scenes, points_in_image) if n < min_points]
    if not low:
        return []
    return [Warning("few_points", f"{len(low)} scene(s) have fewer than {min_points} lidar points in the image at the "
                    f"result: {', '.join(low[:8])}{' ...' if len(low) > 8 else ''}")]


def few_scenes(n_scenes: int, std: np.ndarray | None = None, wanted_mm: float | None = None,
               wanted_deg: float | None = None, min_scenes: int = MIN_SCENES) -> list[Warning]:
    """Too few scenes in absolute terms, or for the spread wanted given a per-parameter std
    (which shrinks as 1 / sqrt(scenes))."""
    out = []
    if n_scenes < min_scenes:
        out.append(Warning("few_scenes", f"only {n_scenes} scene(s); record at least {min_scenes} (the paper uses 20+)"))
    if std is not None and (wanted_mm or wanted_deg):
        std = np.asarray(std, dtype=float)
        ratios = []
        if wanted_mm:
            ratios.append(np.nanmax(std[:3]) / wanted_mm)
        if wanted_deg:
            ratios.append(np.nanmax(std[3:]) / wanted_deg)
        r = max(ratios)
        if r > 1:
            need = int(np.ceil(n_scenes * r * r))
            out.append(Warning("spread_too_large",
                               f"the estimated spread ({', '.join(f'{a} {v:.3g}' for a, v in zip(AXES, std))}) exceeds "
                               f"the wanted {wanted_mm or '-'} mm / {wanted_deg or '-'} deg; about {need} scenes would "
                               f"be needed (spread ~ 1/sqrt(scenes))"))
    return out


def few_places(places: np.ndarray, min_places: int = MIN_SCENES) -> list[Warning]:
    """Scenes that repeat one view: ``places`` holds the place of each scene used
    (:attr:`l2e_studio.objective.SceneStack.places`; scenes taken without moving the rig share
    one). One place pins no translation however many scenes show it, as the verdict says; fewer
    places than ``min_places`` among more scenes count as fewer scenes than they look."""
    places = np.asarray(places)
    n, k = len(places), len(np.unique(places))
    if n < 2 or k == n:
        return []
    if k == 1:
        return [Warning("one_place", f"all {n} scenes show one place (their lidar views agree: the rig did not move "
                                     "between them); one place pins the rotation as one scene does and no translation, "
                                     "however many scenes show it: record scenes at other places")]
    if k < min_places:
        return [Warning("few_places", f"the {n} scenes show only {k} places (scenes taken without moving the rig repeat "
                                      f"one view); record at least {min_places} places")]
    return []


def flat_landscape(sweeps: list, score: str = "MI", max_half_width_m: float = 0.04, max_half_width_deg: float = 1.5,
                   ambiguous: float = 0.9) -> list[Warning]:
    """A flat axis, or a second local maximum on a 1-D sweep through the result (``score``: its name)."""
    out = []
    for s in sweeps:
        limit = max_half_width_m if s.axis in AXES[:3] else max_half_width_deg
        if s.half_width() >= limit:
            out.append(Warning("flat", f"the {score} is flat along {s.axis} (half width {s.half_width():.3g} "
                               f"{'m' if s.axis in AXES[:3] else 'deg'})"))
        if s.secondary_ratio() >= ambiguous:
            unit = "m" if s.axis in AXES[:3] else "deg"
            out.append(Warning("ambiguous", f"on the 1-D sweep of the {score} along {s.axis} through the result "
                               f"(+-{s.offsets[-1]:.3g} {unit}), a second local maximum reaches "
                               f"{100 * s.secondary_ratio():.0f}% of the main one's height above the sweep's minimum"))
    return out


def held_out_used(held_out: list[str], used: list[str] | None) -> list[Warning]:
    """Scenes marked held out that the calibration did use: their scores are not held-out scores."""
    both = [s for s in held_out if used and s in used]
    if not both:
        return []
    return [Warning("held_out_used", f"{len(both)} scene(s) marked held out were used by the calibration: "
                    f"{', '.join(both[:8])}{' ...' if len(both) > 8 else ''}; their scores are not held-out scores")]
