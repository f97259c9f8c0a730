"""The scores a calibration can climb, side by side.

* ``mi``: the paper's mutual information of lidar intensity against the map (:mod:`.mi`). Right
  for accumulated event maps of laser returns, where every lit pixel is a laser spot and
  intensity and event count correlate point by point.
* ``edges``: lidar depth and intensity edges against the map's band-passed gradient
  (:mod:`.edges`). Right for camera images (frame cameras, E2VID reconstructions), where MI
  rewards large regions instead of structure.
"""

from __future__ import annotations

from typing import Iterable

OBJECTIVES = ("mi", "edges")
#: What the edge score's image maps read: every orientation (the default), or only the gradient
#: across the lidar's scan lines (:func:`.edges.scan_gradient`; stronger on sparse multi-scene
#: rigs, fooled more often where every scene shares a misleading structure:
#: benchmarks/results/realdata.md). Here, not in :mod:`.edges`, so ``--help`` imports no numpy.
EDGE_GRADIENTS = ("magnitude", "scan-lines")


def objective_for(map_kinds: Iterable[str], requested: str = "auto") -> str:
    """The objective to climb: ``requested`` unless it is ``auto``, else ``mi`` when every map
    is an accumulated event map and ``edges`` as soon as one is a camera image."""
    if requested != "auto":
        if requested not in OBJECTIVES:
            raise ValueError(f"unknown objective {requested!r}; expected auto or one of {', '.join(OBJECTIVES)}")
        return requested
    return "mi" if all(k == "events" for k in map_kinds) else "edges"
