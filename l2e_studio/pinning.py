"""Is the translation pinned, per camera axis, and what the translation does to a rotation.

Per axis (camera frame: x right, y down, z forward) the scenes pin the translation where moving
it ``PROBE_M`` costs the score a fair share, or both halves of the scenes climb back to it; never
from one place (:func:`translation_axes`). Where they do not, the seed's translation is kept,
and a rotation is only as good as the translation it is paired with: :func:`rotation_lever` says
how far it turns for each centimetre that translation is off, at the depths the score rests on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .evidence import RETURN_M
from .geometry import Extrinsic
from .objective import SceneStack

#: A rotation is paired with a translation measured this well or better (deg): the accuracy the
#: lever's advice asks the translation for
LEVER_TARGET_DEG = 0.1

PROBE_M = 0.05  # translation probes: the score must drop when the result moves this far along each axis ...
#: ... by at least this share of its value, or that axis is not pinned down. Per objective: the
#: edge score is zero-mean by construction (band-passed map), so its relative changes read
#: directly; the MI carries a large pose-independent part (the marginal entropies), which
#: compresses them (synthetic scenes whose translation is recovered to 2 mm lose 5 % over 5 cm).
OBSERVABLE_DROP = {"edges": 0.1, "mi": 0.02}

#: Per camera axis: what moves its translation, and what to record when the scenes do not pin it.
AXIS_ADVICE = {
    "x": "add scenes with near objects (a few metres) whose vertical edges stand in front of a far background",
    "y": "add scenes with near objects whose top or bottom edges are in view (a table, a car's roof at a few metres)",
    "z": "add scenes with near objects at the image's left and right edges",
}


@dataclass(frozen=True)
class AxisPinned:
    """Whether the scenes pin the translation along one camera axis: the share of the score lost
    by moving ``PROBE_M`` along it (the smaller side), against the objective's need, or, where the
    peak is broader than that, both halves of the scenes climbing back to it (``returned``: how
    far from the result the worst of them ended, m; nan where not tried); never from one place
    (``one_place``: one scene, or ``scenes`` scenes of a rig that did not move; see
    :func:`translation_axes`)."""

    axis: str  # "x", "y" or "z" (camera frame: right, down, forward)
    pinned: bool
    drop: float
    one_place: bool = False
    returned: float = float("nan")
    scenes: int = 1

    def line(self) -> str:
        state = "pinned" if self.pinned else "not pinned"
        text = f"{self.axis} is {state} (moving {100 * PROBE_M:.0f} cm costs {100 * self.drop:.0f} % of the score"
        advice = AXIS_ADVICE[self.axis]
        if self.one_place and self.scenes >= 2:
            text += f", but all {self.scenes} scenes show one place, and one place cannot pin a translation"
            advice = f"move the rig between scenes to record other places; {advice}"
        elif self.one_place:
            text += ", but one scene cannot pin a translation"
        elif not np.isnan(self.returned):
            text += (f"; each half of the scenes, moved {100 * PROBE_M:.0f} cm either way, climbs back to within "
                     f"{100 * self.returned:.1f} cm" if self.pinned else
                     f", and a half of the scenes moved {100 * PROBE_M:.0f} cm along it ends "
                     f"{100 * self.returned:.1f} cm from the result")
        return f"{text})" if self.pinned else f"{text}): {advice}"


def translation_axes(drops: np.ndarray, objective: str, n_places: int,
                     returned: np.ndarray | None = None, n_scenes: int | None = None) -> tuple[AxisPinned, ...]:
    """Per camera axis, whether :func:`translation_drops` shows the scenes pin it, or (where the
    drop is short of the objective's need) ``returned`` does: the halves of the places climbing
    back to within ``RETURN_M`` from ``PROBE_M`` either way (:func:`l2e_studio.evidence.climbs_back`;
    nan: not tried).

    One place pins none, be it one scene or ``n_scenes`` scenes of a rig that did not move
    (:mod:`l2e_studio.places`). One scene's probe moves the translation with the rotation held,
    and a rotation of a few tenths of a degree gives most of that score back; its halves (strips
    of one image) share its structure, so they agree on its bias. On the single-scan dev rigs
    results whose checks all passed were 3-25 cm off along axes that cost 20-47 % of the score
    (OpenCalib manual: x 5-7 cm off at a 46 % drop, 7 % with the rotation re-fitted), and one scan
    climbed back along z to a translation 8 cm off (OpenCalib 3). Scenes of one place are that
    one scene again: on LCECalib's static rig a result 20 cm off passed every check of its 18."""
    need = OBSERVABLE_DROP[objective]
    one = n_places < 2
    scenes = n_places if n_scenes is None else n_scenes
    returned = np.full(3, np.nan) if returned is None else np.asarray(returned, dtype=float)
    return tuple(AxisPinned(axis, bool(d >= need or r <= RETURN_M) and not one, float(d), one, float(r), scenes)
                 for axis, d, r in zip("xyz", drops, returned))


def translation_drops(stack: SceneStack, res: Extrinsic, at_res: float) -> np.ndarray:
    """(3,) the share of the score lost by moving ``PROBE_M`` either way along x, y and z (the
    smaller of the two sides): a flat axis loses ~0, a pinned one a good part of its score."""
    moved = stack.scores([res.perturbed(sign * PROBE_M * np.eye(3)[k], np.zeros(3)) for k in range(3)
                          for sign in (-1.0, 1.0)])
    worst = moved.reshape(3, 2).max(axis=1)
    return (at_res - worst) / abs(at_res) if at_res != 0 else np.zeros(3)


def rotation_lever(stack: SceneStack, at: Extrinsic) -> float:
    """How far (deg) the best rotation turns for each centimetre its translation is off sideways
    (camera x or y): a sideways shift moves a point at depth Z by f * shift / Z pixels, a rotation
    moves every point by f * angle, so the rotation that makes up for the shift best turns by the
    shift times the mean of 1 / Z over the points the score rests on (weighted as it weights them:
    the edge weights, or all alike for the MI; the points in the image at ``at``). About 0.05 deg
    a cm for a street seen at 10-20 m, 0.3 for a room at 2-3 m; nan when no point is in view."""
    _, inside = stack.project(at)
    pts = stack.points[:, inside].astype(np.float64)
    depth = (at.R[2] @ pts) + at.translation[2]
    w = np.ones(depth.size) if stack.weights is None else stack.weights[inside].astype(np.float64)
    ok = depth > 0
    if not np.any(w[ok] > 0):
        return float("nan")
    return float(np.degrees(0.01 * np.sum(w[ok] / depth[ok]) / np.sum(w[ok])))
