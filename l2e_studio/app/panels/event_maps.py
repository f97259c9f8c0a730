"""The selected scene's event map, when it was accumulated from a raw recording: the window,
the start and the hot-pixel suppression, checked as typed, and Rebuild (in the background, for
this scene or every scene from raw events). Maps read as images say so and offer nothing."""

from __future__ import annotations

from ..checks import AccumulationChecked, check_accumulation
from ..context import Workbench
from ..exact import format_value
from ...io.events import Accumulation, EventStats

IDLE_STATUS = ""


def accumulation_fields(acc: Accumulation) -> tuple[str, str, str]:
    """The three fields' text for ``acc`` (hot pixels ``off`` or the sigma)."""
    hot = "off" if acc.hot_pixel_sigma is None else format_value(acc.hot_pixel_sigma)
    return format_value(acc.window_s), format_value(acc.start_s), hot


def describe_recording(info: EventStats | str | None) -> str:
    if info is None:
        return "recording: reading its length..."
    if isinstance(info, str):
        return f"recording: cannot read its length ({info})"
    return f"recording: **{info.duration_s:.3f} s**, {info.count:,} events"


class EventMapsPanel:
    def __init__(self, app: Workbench) -> None:
        self.app = app
        gui = app.server.gui
        with gui.add_folder("Event map"):
            self.source = gui.add_markdown("")
            self.window = gui.add_text("Window (s)", "3", hint="Events are counted over this many seconds: (0, 3600]")
            self.w_problem = gui.add_markdown("", visible=False)
            self.start = gui.add_text("Start (s)", "0", hint="Seconds into the recording where the window starts")
            self.s_problem = gui.add_markdown("", visible=False)
            self.hot = gui.add_text("Hot-pixel σ", "off",
                                    hint="off, or σ in (0, 1000]: pixels firing above median + σ·MAD are zeroed")
            self.h_problem = gui.add_markdown("", visible=False)
            self.apply_all = gui.add_checkbox("Apply to all event scenes", False,
                                              hint="Rebuild the map of every scene read from raw events, not only this one")
            self.rebuild = gui.add_button("Rebuild map", hint="Accumulate the map again in the background")
            self.status = gui.add_markdown(IDLE_STATUS)
        self._shown: int | None = None  # the scene whose settings the fields hold
        for handle in (self.window, self.start, self.hot):
            handle.on_update(lambda _: self.check())
        self.apply_all.on_update(lambda _: self.check())
        self.rebuild.on_click(self._on_rebuild)
        self.show()

    def _selected(self) -> int:
        return self.app.state.snapshot().selected

    def checked(self) -> AccumulationChecked:
        index = self._selected()
        info = self.app.recording(index)
        duration = info.duration_s if isinstance(info, EventStats) else None
        return check_accumulation(self.window.value, self.start.value, self.hot.value, duration)

    def show(self, reset_fields: bool = False) -> None:
        """Describe the selected scene's map; the fields take its settings when another scene is
        selected (or ``reset_fields``)."""
        index = self._selected()
        scene = self.app.scene_set.scenes[index]
        acc = scene.accumulation
        if acc is None:
            name = scene.map_path.name if scene.map_path is not None else "in memory"
            self.source.content = (f"The map of **{scene.name}** (`{name}`) is read as an image, not accumulated "
                                   "from raw events: there is nothing to rebuild.")
        else:
            self.source.content = (f"**{scene.name}** from raw events `{scene.map_path.name}`  \n"
                                   f"{describe_recording(self.app.recording(index))}  \n"
                                   f"map now: {acc.describe()}")
            if reset_fields or index != self._shown:
                self.window.value, self.start.value, self.hot.value = accumulation_fields(acc)
        self._shown = index
        for handle in (self.window, self.start, self.hot):
            handle.disabled = acc is None
        self.check()

    def check(self) -> AccumulationChecked:
        """Show each field's problem beside it; Rebuild is enabled only when it can run."""
        result = self.checked()
        scene = self.app.scene_set.scenes[self._selected()]
        for problem, note in zip(result.problems, (self.w_problem, self.s_problem, self.h_problem)):
            note.content = f"⚠ {problem}" if problem and scene.accumulation is not None else ""
            note.visible = bool(note.content)
        if result.note and scene.accumulation is not None:
            self.s_problem.content, self.s_problem.visible = f"Note: {result.note}", True
        reason = self.blocker(result)
        self.rebuild.disabled = bool(reason)
        self.apply_all.disabled = scene.accumulation is None
        if reason and not self.app.rebuilding():
            self.status.content = f"Rebuild is disabled: {reason}."
        elif self.status.content.startswith("Rebuild is disabled"):
            self.status.content = IDLE_STATUS
        return result

    def blocker(self, result: AccumulationChecked) -> str:
        """Why Rebuild cannot run now ("" when it can)."""
        if self.app.scene_set.scenes[self._selected()].accumulation is None:
            return "this scene's map is not from raw events"
        if self.app.state.snapshot().run.active:
            return "an optimisation is running (it keeps the maps it started with); rebuild when it ends"
        if self.app.rebuilding():
            return "a rebuild is in progress"
        if result.settings is None:
            return "fix the settings marked above"
        return ""

    def show_status(self, text: str) -> None:
        self.status.content = text

    def _on_rebuild(self, event) -> None:
        result = self.check()
        if result.settings is None or self.rebuild.disabled:
            return
        try:
            self.app.rebuild_maps(result.settings, bool(self.apply_all.value))
        except RuntimeError as exc:
            self.status.content = f"✗ {exc}"
            self.app.notify(event.client, "Cannot rebuild", str(exc), color="red")
