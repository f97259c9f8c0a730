"""Scenes held out of a run (excluded from the optimisation) still get scored: MI at the
run's seed and at its result, from the readout's stack of every scene (pure, no viser)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

from .readout import MiReadout


@dataclass(frozen=True)
class HeldOutScore:
    """One held-out scene: its MI at the run's seed and at its result (readout sigma)."""

    name: str
    score_seed: float
    score_result: float


def held_out_scores(result: Any, scene_names: Sequence[str], readout: MiReadout) -> list[HeldOutScore]:
    """Every scene of ``scene_names`` that the run did not optimise over, scored."""
    used = set(result.scene_names)
    held = [i for i, n in enumerate(scene_names) if n not in used]
    if not held:
        return []
    everything = [True] * len(scene_names)
    at_seed = readout.read(result.seed, everything).per_scene
    at_result = readout.read(result.extrinsic, everything).per_scene
    return [HeldOutScore(scene_names[i], float(at_seed[i]), float(at_result[i])) for i in held]


def held_out_section(rows: Sequence[HeldOutScore]) -> list[dict]:
    """The result file's entries for held-out scenes (``held_out: true``)."""
    def f(x: float) -> float | None:
        return float(x) if x == x and abs(x) != float("inf") else None

    return [{"scene": r.name, "seed": f(r.score_seed), "result": f(r.score_result), "held_out": True} for r in rows]
