"""The scenes as the engine scores them, and the scores the optimiser climbs.

* :mod:`.stack`: :class:`SceneStack`, every scene in one set of flat arrays, with the reporting
  scores (the paper's MI at the nearest pixel, the edge score) and the point subsets the verdict
  and the QA studies take of it;
* :mod:`.smooth`: :class:`MIObjective` and :class:`EdgeObjective`, those scores made smooth over
  a fixed point set, with their analytic gradients (what :mod:`l2e_studio.calibrate` climbs).
"""

from .smooth import MIN_DEPTH, EdgeObjective, MapObjective, MIObjective, single_threaded_blas
from .stack import SceneStack, evenly

__all__ = ["MIN_DEPTH", "EdgeObjective", "MIObjective", "MapObjective", "SceneStack", "evenly", "single_threaded_blas"]
