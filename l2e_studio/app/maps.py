"""The workbench's event maps rebuilt from their raw recordings: starting a rebuild, a new map
reaching every view, the recordings' lengths for the Event map fields.

The threading lives in :mod:`l2e_studio.app.rebuild` (no viser); this is the part that touches
the session: the readout, the displays, the panels. The App delegates to it and stays a
coordinator."""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..io.events import Accumulation, EventStats
from ..scenes import Scene
from .display import SceneDisplay
from .rebuild import MapRebuilder, RebuildSummary, RecordingInfo

if TYPE_CHECKING:
    from .server import App


class EventMapSession:
    """Rebuilds of the scenes' event maps, and the recordings' lengths, for one workbench."""

    def __init__(self, app: "App") -> None:
        self.app = app
        self.recordings = RecordingInfo()  # lengths of the raw event recordings, read on first need
        self.rebuilder = MapRebuilder(app.camera.width, app.camera.height, self._status, self._rebuilt, self._finished)

    def recording(self, index: int) -> EventStats | str | None:
        """Scene ``index``'s raw recording: its stats, why they cannot be read, or None (not yet
        read, or the map is not from raw events)."""
        scene = self.app.scene_set.scenes[index]
        return None if scene.accumulation is None or scene.map_path is None else self.recordings.get(scene.map_path)

    def rebuilding(self) -> bool:
        """True while event maps are being rebuilt."""
        return self.rebuilder.busy()

    def rebuild(self, settings: Accumulation, all_event_scenes: bool = False) -> None:
        """Accumulate the selected scene's map again (or every scene's from raw events) with
        ``settings``, in the background. Raises RuntimeError (nothing starts) during a run: the
        run keeps the maps it started with, so a rebuild waits for its end."""
        app = self.app
        with app.ui_lock:
            if app.state.snapshot().run.active:
                raise RuntimeError("an optimisation is running (it keeps the maps it started with); rebuild when it ends")
            scenes = app.scene_set.scenes
            selected = app.state.snapshot().selected
            targets = [i for i, sc in enumerate(scenes) if sc.accumulation is not None] if all_event_scenes else [selected]
            if not targets or scenes[selected].accumulation is None and not all_event_scenes:
                raise RuntimeError(f"the map of {scenes[selected].name} is not from raw events; there is nothing to rebuild")
            self.rebuilder.start([(i, scenes[i]) for i in targets], settings)
            app.event_maps.check()
            app.optimise.show_start()

    def read_recording(self) -> None:
        """Read the selected scene's recording length (once per file) for the Event map fields."""
        app = self.app
        index = app.state.snapshot().selected
        scene = app.scene_set.scenes[index]
        if scene.accumulation is None or scene.map_path is None or self.recordings.get(scene.map_path) is not None:
            return
        self.recordings.compute(scene.map_path)
        with app.ui_lock:
            if app.state.snapshot().selected == index:
                app.event_maps.show()

    def _status(self, text: str) -> None:
        self.app.event_maps.show_status(text)

    def _rebuilt(self, index: int, scene: Scene) -> None:
        """A new map for scene ``index``: the readout, the display caches and every view follow."""
        app = self.app
        with app.ui_lock:
            app.readout.set_map(index, scene.event_map)  # first: it refuses a map that does not fit
            app.scene_set.scenes[index] = scene
            app.displays[index] = SceneDisplay(scene)  # the old display caches go with the old map
            app.view3d.show_map(index)
            if index == app.state.snapshot().selected:
                app.event_maps.show()
        app.views.overlay_worker.poke()
        app.views.mi_worker.poke()
        app.views.compare_worker.poke()

    def _finished(self, summary: RebuildSummary) -> None:
        app = self.app
        with app.ui_lock:
            app.event_maps.show_status(summary.line())
            app.event_maps.show()
            app.optimise.show_start()
        if summary.errors:
            app.notify_all("Map rebuild failed" if not summary.rebuilt else "Some maps were not rebuilt",
                           "; ".join(summary.errors[:3]), color="red")
