"""The narrow interface the GUI panels see of the workbench.

Panels (``app/panels/*``) are handed an object that satisfies :class:`Workbench` and use only
what is listed here; they never import :mod:`l2e_studio.app.server`, which builds them. The
server's :class:`~l2e_studio.app.server.App` is the one implementation; tests may pass fakes.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, Sequence

if TYPE_CHECKING:  # types only: nothing here imports viser or the engine at run time
    import numpy as np
    import viser

    from ..calibrate import CalibrationSettings
    from ..camera import CameraModel
    from ..geometry import Extrinsic
    from ..scenes import SceneSet
    from .display import SceneDisplay
    from .readout import MiReading, MiReadout
    from .state import SessionState


class Workbench(Protocol):
    """What a panel may read and ask for. Reading: the viser server (to build widgets), the
    shared state, the scenes and their displays, the MI readout. Asking: the methods below,
    each of which updates every other view itself."""

    server: "viser.ViserServer"
    state: "SessionState"
    scene_set: "SceneSet"
    camera: "CameraModel"
    displays: "Sequence[SceneDisplay]"
    readout: "MiReadout"
    reading: "MiReading | None"
    out_dir: Path

    # --- messages ---------------------------------------------------------------------------
    def notify(self, client: Any, title: str, body: str, color: str | None = None) -> None: ...

    # --- the extrinsic ----------------------------------------------------------------------
    def set_extrinsic(self, extrinsic: "Extrinsic", source: str = "", values: "np.ndarray | None" = None) -> None: ...
    def undo(self) -> None: ...
    def redo(self) -> None: ...

    # --- scenes and display -----------------------------------------------------------------
    def select_scene(self, index: int) -> None: ...
    def inclusion_changed(self) -> None: ...
    def display_changed(self) -> None: ...
    def compare_changed(self) -> None: ...
    def image_clicked(self, x: float, y: float) -> bool: ...
    def current_pairs(self) -> list: ...
    def sigma_changed(self, sigma: float) -> None: ...
    def follow_changed(self, follow: bool) -> None: ...

    # --- runs and results -------------------------------------------------------------------
    def start_run(self, settings: "CalibrationSettings") -> int: ...
    def cancel_run(self) -> bool: ...
    def cancel_requested(self) -> bool: ...
    def accept_result(self) -> None: ...
    def discard_result(self) -> None: ...
    def save_result(self) -> tuple[Path, Path | None]: ...
    def set_out_dir(self, text: str) -> str: ...
