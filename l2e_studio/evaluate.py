"""Is a calibration trustworthy? Landscape sharpness and stability across scene subsets.

MI has a maximum wherever it has one, so a converged run says little by itself. Two checks
catch the failure the design notes warn about (a few street scenes of a frame camera whose MI
peak sits degrees from the truth):

* **sharpness**: how much the MI drops when the result is moved by a small step along each of
  the six axes. A flat axis means the data barely constrain it.
* **subset stability**: calibrate again on random halves of the scenes, from the same seed. If
  the answer moves with the scene subset, the result depends on which scenes were recorded.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np

from .calibrate import CalibrationSettings, calibrate
from .geometry import Extrinsic
from .objective import SceneStack

AXES = ("x", "y", "z", "roll", "pitch", "yaw")
STEP_M = 0.02  # sharpness probes: 2 cm ...
STEP_DEG = 0.5  # ... and 0.5 deg, both ways, about the camera axes
FLAT_NATS = 1e-3  # a drop below this over a probe step is "flat"
UNSTABLE_DEG = 0.2  # subset results further apart than this (or UNSTABLE_M) are "unstable"
UNSTABLE_M = 0.02


@dataclass
class QualityReport:
    """What :func:`assess` found; ``warnings`` holds one line per problem (empty = none)."""

    sharpness: np.ndarray  # (6,) mean MI drop (nats) for a probe step along x, y, z, roll, pitch, yaw
    subset_rotation_deg: float | None  # largest rotation between a subset result and the result
    subset_translation_m: float | None
    subsets: int
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict:
        return {
            "sharpness_nats": {a: float(v) for a, v in zip(AXES, self.sharpness)},
            "probe_step": {"translation_m": STEP_M, "rotation_deg": STEP_DEG},
            "subsets": self.subsets,
            "subset_rotation_deg": self.subset_rotation_deg,
            "subset_translation_m": self.subset_translation_m,
            "warnings": list(self.warnings),
        }


def sharpness(stack: SceneStack, ext: Extrinsic) -> np.ndarray:
    """Mean drop of the stack's score for a step of ``STEP_M`` / ``STEP_DEG`` along each axis."""
    centre = stack.score(ext, per_scene=False)[0]
    drops = np.zeros(6)
    for k in range(6):
        step = np.zeros(6)
        step[k] = STEP_M if k < 3 else np.radians(STEP_DEG)
        vals = [stack.score(ext.perturbed(s * step[:3], s * step[3:]), per_scene=False)[0] for s in (-1.0, 1.0)]
        drops[k] = centre - float(np.mean(vals))
    return drops


def assess(
    stack: SceneStack,
    result: Extrinsic,
    seed: Extrinsic,
    settings: CalibrationSettings = CalibrationSettings(),
    subsets: int = 3,
    rng_seed: int = 0,
    cancel: threading.Event | None = None,
) -> QualityReport:
    """Probe the MI around ``result`` and recalibrate from ``seed`` on random halves of the scenes."""
    warnings: list[str] = []
    drops = sharpness(stack, result)
    for axis, drop in zip(AXES, drops):
        if drop < FLAT_NATS:
            unit = f"{100 * STEP_M:.0f} cm" if axis in AXES[:3] else f"{STEP_DEG} deg"
            warnings.append(f"flat along {axis}: moving {unit} changes the score by only {drop:+.4f}")

    rot = trans = None
    if stack.n_scenes < 2:
        warnings.append("a single scene: the result cannot be checked against other scenes; record more (20+)")
        subsets = 0
    else:
        rng = np.random.default_rng(rng_seed)
        rot, trans = 0.0, 0.0
        half = max(1, stack.n_scenes // 2)
        for _ in range(subsets):
            chosen = rng.choice(stack.n_scenes, half, replace=False)
            sub = calibrate(stack.subset(chosen), None, seed, settings, cancel=cancel)
            if sub.cancelled:
                break
            deg, m = sub.extrinsic.error_to(result)
            rot, trans = max(rot, deg), max(trans, m)
        if rot > UNSTABLE_DEG or trans > UNSTABLE_M:
            warnings.append(
                f"unstable: calibrating on half of the scenes moves the result by up to {rot:.2f} deg / "
                f"{100 * trans:.1f} cm; add scenes or check the seed"
            )
    return QualityReport(drops, rot, trans, subsets, warnings)
