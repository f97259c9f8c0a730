"""The live MI readout: the engine's MI of every scene, and of the included ones pooled.

One :class:`~l2e_studio.objective.SceneStack` of all loaded scenes is built once (and again
when the smoothing sigma changes; a rebuilt event map replaces only its scene's); one evaluation gives the per-scene values and the joint
histograms, pooled by the engine over the included scenes. No MI arithmetic lives here.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..camera import CameraModel
from ..geometry import Extrinsic
from ..scoring import objective_for
from .text import score_label
from ..objective import SceneStack
from ..scenes import Scene

#: Points that cannot reach the image within this much of the reference pose are dropped
#: from the readout stack (the sliders' default range).
READOUT_REACH_M = 1.0
READOUT_REACH_DEG = 35.0


@dataclass(frozen=True)
class MiReading:
    """MI at one extrinsic: pooled over the included scenes, and per scene (all scenes)."""

    extrinsic: Extrinsic
    total: float
    per_scene: np.ndarray
    included: tuple[bool, ...]


class MiReadout:
    """Evaluates the calibration score for the GUI (the objective the optimiser climbs: the
    paper's MI for event maps, the edge score for camera images); a lock orders reads against
    sigma changes."""

    def __init__(
        self, scenes: Sequence[Scene], camera: CameraModel, reference: Extrinsic, sigma: float = 5.0, objective: str = "auto",
        gradient: str = "magnitude",
    ) -> None:
        self._lock = threading.Lock()
        self.generation = 0  # counts changes of the stack's maps (sigma or a map)
        self._stack = SceneStack.build(
            scenes, camera, sigma, reference=reference,
            reach_m=READOUT_REACH_M, reach_deg=READOUT_REACH_DEG,
            objective=objective_for([sc.map_kind for sc in scenes], objective), gradient=gradient,
        )

    @property
    def label(self) -> str:
        """The score's on-screen name ("MI", "edge score")."""
        return score_label(self._stack.objective_name)

    @property
    def sigma(self) -> float:
        return self._stack.sigma

    @property
    def stack(self) -> SceneStack:
        """The current stack (immutable, so other threads may use it; the optimiser does)."""
        return self._stack

    def set_sigma(self, sigma: float) -> None:
        with self._lock:
            self._stack = self._stack.with_sigma(float(sigma))
            self.generation += 1

    def set_map(self, index: int, raw_map: np.ndarray) -> None:
        """Score scene ``index`` against ``raw_map`` from now on (a stack already handed out,
        e.g. to a running optimisation, keeps its maps)."""
        with self._lock:
            self._stack = self._stack.with_map(index, raw_map)
            self.generation += 1

    def read(self, extrinsic: Extrinsic, included: Sequence[bool]) -> MiReading:
        """MI of each scene and of the ``included`` scenes' histograms pooled together (edge
        maps prepared again for ``extrinsic`` when it turned the lidar's axis far from theirs)."""
        mask = np.asarray(included, dtype=bool)
        with self._lock:
            aimed = self._stack.aimed_at(extrinsic)  # a seed tuned far from the first one
            if aimed is not self._stack:
                self._stack = aimed
                self.generation += 1
            total, per_scene = self._stack.score(extrinsic, pooled=mask)
        return MiReading(extrinsic, float(total), np.asarray(per_scene, float), tuple(bool(b) for b in mask))
