"""The paper's Table III: candidate calibrations scored scene by scene and in total, on held-out
scenes, by groups of scenes, with the difference between any two candidates.

A *candidate* is a named extrinsic (the seed, a result, an imported file, a previous release).
:func:`score` evaluates the paper's MI of every candidate on every scene and pools the scenes of
each group; :func:`calibrate_held_out` calibrates on the training scenes only and scores the
result on the others.
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from ..calibrate import CalibrationResult, CalibrationSettings, calibrate
from ..errors import InputError
from ..geometry import Extrinsic
from ..objective import SceneStack


@dataclass(frozen=True)
class Candidate:
    name: str
    extrinsic: Extrinsic
    source: str = ""  # where it came from (a file path, "seed", "result" ...)


def load_candidates(specs: Sequence[str]) -> list[Candidate]:
    """``NAME=FILE`` (or just ``FILE``, named by its stem) -> candidates, via ``load_seed``."""
    from ..io.cameras import load_seed

    out: list[Candidate] = []
    for spec in specs:
        name, _, path = spec.partition("=") if "=" in spec else (Path(spec).stem, "", spec)
        if not name:
            raise InputError(spec, "a candidate needs a name: NAME=FILE")
        out.append(Candidate(name, load_seed(path), str(path)))
    names = [c.name for c in out]
    if len(set(names)) != len(names):
        raise InputError(None, f"candidate names must differ: {', '.join(names)}")
    return out


def group_masks(names: Sequence[str], groups: dict[str, Sequence[str]] | None) -> dict[str, np.ndarray]:
    """``{group: [glob, ...]}`` -> ``{group: mask over names}``; ``"all"`` is always there, and
    with groups a ``"rest"`` group holds the scenes no pattern matched (when there are any)."""
    names = list(names)
    out: dict[str, np.ndarray] = {}
    taken = np.zeros(len(names), dtype=bool)
    for g, patterns in (groups or {}).items():
        pats = [patterns] if isinstance(patterns, str) else list(patterns)
        m = np.array([any(fnmatch.fnmatchcase(n, p) for p in pats) for n in names], dtype=bool)
        out[g] = m
        taken |= m
    if groups and (~taken).any() and "rest" not in out:
        out["rest"] = ~taken
    out["all"] = np.ones(len(names), dtype=bool)
    return out


def parse_groups(specs: Sequence[str]) -> dict[str, list[str]]:
    """``NAME=GLOB[,GLOB...]`` strings -> ``{name: [globs]}``."""
    out: dict[str, list[str]] = {}
    for spec in specs:
        name, sep, globs = spec.partition("=")
        if not sep or not name or not globs:
            raise InputError(None, f"bad group {spec!r}: expected NAME=GLOB[,GLOB...] (e.g. checker='checker*')")
        out[name] = [g for g in globs.split(",") if g]
    return out


def difference(a: Extrinsic, b: Extrinsic) -> dict:
    """How far ``b`` is from ``a``: total rotation (deg) and translation (mm), and per camera axis."""
    dt, dw = a.delta_to(b)
    deg, m = a.error_to(b)
    return {
        "rotation_deg": deg,
        "translation_mm": 1000.0 * m,
        "per_axis_mm": (1000.0 * dt).tolist(),
        "per_axis_deg": np.degrees(dw).tolist(),
    }


@dataclass
class ScoreTable:
    """MI of each candidate on each scene, pooled per group, and the pairwise differences."""

    candidates: list[Candidate]
    scenes: list[str]
    per_scene: np.ndarray  # (C, S) paper's MI, nats
    groups: dict[str, np.ndarray]  # name -> mask over scenes
    pooled: dict[str, np.ndarray]  # name -> (C,) MI of the group's scenes pooled
    held_out: np.ndarray  # (S,) bool: scenes not used for the calibration being judged
    points_in_image: np.ndarray  # (C, S) counts
    differences: dict[tuple[str, str], dict] = field(default_factory=dict)

    def best(self, group: str = "all") -> str:
        return self.candidates[int(np.nanargmax(self.pooled[group]))].name

    def to_dict(self) -> dict:
        names = [c.name for c in self.candidates]
        return {
            "candidates": [{"name": c.name, "source": c.source, "T_cam_lidar": np.round(c.extrinsic.matrix, 10).tolist()}
                           for c in self.candidates],
            "scenes": [
                {"scene": s, "held_out": bool(self.held_out[j]),
                 **{n: _f(self.per_scene[i, j]) for i, n in enumerate(names)},
                 "points_in_image": {n: int(self.points_in_image[i, j]) for i, n in enumerate(names)}}
                for j, s in enumerate(self.scenes)
            ],
            "groups": {
                g: {"scenes": int(m.sum()), **{n: _f(self.pooled[g][i]) for i, n in enumerate(names)}}
                for g, m in self.groups.items()
            },
            "differences": [{"a": a, "b": b, **d} for (a, b), d in self.differences.items()],
        }

    def rows(self) -> list[list[str]]:
        """A plain text table: one row per scene, then one per group (pooled)."""
        out = []
        for j, s in enumerate(self.scenes):
            out.append([s + (" (held out)" if self.held_out[j] else "")] + [f"{v:.4f}" for v in self.per_scene[:, j]])
        for g, m in self.groups.items():
            out.append([f"[{g}: {int(m.sum())} scenes pooled]"] + [f"{v:.4f}" for v in self.pooled[g]])
        return out


def score(
    stack: SceneStack,
    candidates: Sequence[Candidate],
    groups: dict[str, Sequence[str]] | None = None,
    held_out: np.ndarray | None = None,
) -> ScoreTable:
    """Score every candidate on every scene of ``stack`` (the paper's MI at the stack's sigma).

    ``held_out`` marks scenes that the judged calibration did not use; they also form the group
    ``"held out"`` (pooled) when some but not all scenes are held out.
    """
    if not candidates:
        raise InputError(None, "no candidate calibrations to score")
    names = list(stack.names)
    held = np.zeros(len(names), dtype=bool) if held_out is None else np.asarray(held_out, dtype=bool)
    masks = group_masks(names, groups)
    if held.any() and not held.all():
        masks = {"held out": held, "training": ~held, **masks}
    C, S = len(candidates), len(names)
    per = np.zeros((C, S))
    counts = np.zeros((C, S), dtype=np.int64)
    pooled = {g: np.zeros(C) for g in masks}
    for i, c in enumerate(candidates):
        joints = stack.joint_histograms(c.extrinsic, per_scene=True)
        from ..scoring.mi import mi_from_joint_histogram

        per[i] = [mi_from_joint_histogram(j) for j in joints]
        counts[i] = joints.sum(axis=(1, 2)).astype(np.int64)
        for g, m in masks.items():
            pooled[g][i] = mi_from_joint_histogram(joints[m].sum(axis=0)) if m.any() else np.nan
    table = ScoreTable(list(candidates), names, per, masks, pooled, held, counts)
    for a in range(C):
        for b in range(a + 1, C):
            table.differences[(candidates[a].name, candidates[b].name)] = difference(
                candidates[a].extrinsic, candidates[b].extrinsic)
    return table


def split_scenes(names: Sequence[str], held_out: Sequence[str] | None = None, fraction: float | None = None,
                 rng_seed: int = 0) -> np.ndarray:
    """Mask of held-out scenes: those matching any glob in ``held_out``, else a random
    ``fraction`` of them (at least one, leaving at least one for training)."""
    names = list(names)
    if held_out:
        m = np.array([any(fnmatch.fnmatchcase(n, p) for p in held_out) for n in names], dtype=bool)
    elif fraction:
        if not 0 < fraction < 1:
            raise InputError(None, f"the held-out fraction must be between 0 and 1, got {fraction}")
        k = min(len(names) - 1, max(1, int(round(fraction * len(names)))))
        m = np.zeros(len(names), dtype=bool)
        m[np.random.default_rng(rng_seed).choice(len(names), k, replace=False)] = True
    else:
        return np.zeros(len(names), dtype=bool)
    if m.all():
        raise InputError(None, "every scene is held out: none left to calibrate on")
    if len(names) and not m.any():
        raise InputError(None, f"no scene matches the held-out patterns {list(held_out or [])}")
    return m


def calibrate_held_out(
    stack: SceneStack, seed: Extrinsic, held_out: np.ndarray, settings: CalibrationSettings = CalibrationSettings(),
    **kwargs,
) -> CalibrationResult:
    """Calibrate on the scenes not held out (from ``seed``); score with :func:`score` afterwards."""
    train = ~np.asarray(held_out, dtype=bool)
    return calibrate(stack.subset(np.flatnonzero(train)), None, seed, settings, **kwargs)


def _f(x) -> float | None:
    return None if not np.isfinite(x) else round(float(x), 6)
