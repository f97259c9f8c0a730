"""What a result hands back, told apart from the optimiser's own answer, and both scored on the
readout's scale (the same number the Seed tab shows once the result is accepted). Pure, no viser."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..geometry import Extrinsic
from .readout import MiReadout


@dataclass(frozen=True)
class Answer:
    """One extrinsic of a result: what it is, and its score pooled over the run's scenes."""

    what: str
    extrinsic: Extrinsic
    score: float


@dataclass(frozen=True)
class ResultScores:
    """A run's seed, the optimiser's answer and what Accept sets (``accepted``: the verdict's
    extrinsic when it trusts the result), with what the saved file and exports hand back
    (``file``), all scored by the readout over the run's scenes."""

    seed: Answer
    optimiser: Answer
    accepted: Answer
    file: Answer
    per_scene_accepted: np.ndarray  # every scene of the session, at ``accepted``
    per_scene_seed: np.ndarray | None = None  # every scene of the session, at the run's seed
    label: str = ""  # the readout's score name: the run's own may differ (a checkerboard run's "board planes")

    @property
    def same(self) -> bool:
        """The optimiser's answer is what Accept sets (nothing replaced by the verdict)."""
        return np.allclose(self.optimiser.extrinsic.matrix, self.accepted.extrinsic.matrix, atol=1e-12)


def what_is_handed_back(verdict: Any, judging_cancelled: bool = False, cancelled: bool = False) -> str:
    """The saved file's and the exports' transform, in words."""
    if verdict is None:
        return ("the optimiser's best point so far (run cancelled, not judged)" if cancelled
                else "the optimiser's answer (judging cancelled, not judged)" if judging_cancelled
                else "the optimiser's answer (not judged)")
    if verdict.seed_stands:
        return f"the seed, confirmed: the optimiser's answer is within its own spread of it ({verdict.status})"
    if verdict.settled:
        return (f"the optimiser's answer with the seed's {' and '.join(verdict.from_seed())} "
                f"(where it moved within its spread, or the scenes do not pin it; {verdict.status})")
    if verdict.status == "trusted":
        return "the optimiser's answer (trusted)"
    if verdict.status == "trusted-rotation":
        return "the checked rotation with the seed's translation (trusted-rotation)"
    return "the seed (not trusted)" if verdict.kept_seed else "the optimiser's answer (marked not trusted)"


def result_scores(snap: Any, scene_names: list[str], readout: MiReadout) -> ResultScores | None:
    """Score ``snap.result``'s seed, the optimiser's answer, and what is accepted / saved."""
    r = snap.result
    if r is None:
        return None
    used = set(r.scene_names)
    mask = [n in used for n in scene_names]

    def score(ext: Extrinsic) -> float:
        return readout.read(ext, mask).total

    accepted_ext, file_ext = snap.accepted, snap.handed_back
    at_accepted = readout.read(accepted_ext, mask)  # pooled over the run's scenes, and every scene's own
    at_seed = readout.read(r.seed, mask)
    file_what = what_is_handed_back(snap.verdict, snap.judging_cancelled, bool(r.cancelled))
    accepted = Answer(file_what if accepted_ext is file_ext else "the optimiser's answer (not trusted: your call)",
                      accepted_ext, at_accepted.total)
    return ResultScores(
        seed=Answer("the run's seed", r.seed, at_seed.total),
        optimiser=Answer("the optimiser's own answer", r.extrinsic,
                         accepted.score if r.extrinsic is accepted_ext else score(r.extrinsic)),
        accepted=accepted,
        file=accepted if file_ext is accepted_ext else Answer(file_what, file_ext, score(file_ext)),
        per_scene_accepted=np.asarray(at_accepted.per_scene, dtype=np.float64),
        per_scene_seed=np.asarray(at_seed.per_scene, dtype=np.float64),
        label=readout.label,
    )
