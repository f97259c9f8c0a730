"""The scene list: pick the scene shown, include or exclude scenes from the optimisation,
see every scene's MI at the current extrinsic and the scenes that failed to load."""

from __future__ import annotations

from ..context import Workbench
from ..readout import MiReading
from ..text import num


class ScenesPanel:
    def __init__(self, app: Workbench) -> None:
        self.app = app
        gui = app.server.gui
        ss = app.scene_set
        names = app.state.scene_names
        gui.add_markdown(f"**{len(names)} scenes** from `{ss.root}`"
                         + (f" · **{len(ss.failures)} failed to load**" if ss.failures else ""))
        self.dropdown = gui.add_dropdown("Scene", names, initial_value=names[0])
        self.include = gui.add_checkbox("Use in optimisation", True,
                                        hint="Excluded scenes are held out: still scored, not optimised over")
        self.all_on = gui.add_button_group("Include", ("all", "none"))
        self.table = gui.add_markdown(self._table(None))
        self.failures = gui.add_markdown(self._failures(), visible=bool(ss.failures or ss.unpaired))

        @self.dropdown.on_update
        def _(event) -> None:
            if event.client is None:
                return
            app.select_scene(names.index(self.dropdown.value))

        @self.include.on_update
        def _(event) -> None:
            if event.client is None:
                return
            app.state.set_included(app.state.snapshot().selected, self.include.value)
            app.inclusion_changed()

        @self.all_on.on_click
        def _(event) -> None:
            app.state.set_all_included(self.all_on.value == "all")
            app.inclusion_changed()

    def show_selection(self) -> None:
        snap = self.app.state.snapshot()
        self.dropdown.value = self.app.state.scene_names[snap.selected]
        self.include.value = snap.included[snap.selected]
        self.table.content = self._table(self.app.reading)

    def show_mi(self, reading: MiReading) -> None:
        self.table.content = self._table(reading)

    def _table(self, reading: MiReading | None) -> str:
        snap = self.app.state.snapshot()
        n_in = sum(snap.included)
        rows = [f"Optimising over **{n_in}** of {len(snap.included)} scenes.", "",
                "| | scene | points | MI now |", "|:-:|:--|--:|--:|"]
        for i, name in enumerate(self.app.state.scene_names):
            mark = "✓" if snap.included[i] else "–"
            mi = "" if reading is None else num(reading.per_scene[i])
            label = f"**{name}**" if i == snap.selected else name
            rows.append(f"| {mark} | {label} | {self.app.scene_set.scenes[i].points.shape[0]} | {mi} |")
        return "\n".join(rows)

    def _failures(self) -> str:
        ss = self.app.scene_set
        lines = ["**Not loaded:**", ""]
        lines += [f"- ✗ `{f.name}`: {f.error}" for f in ss.failures]
        lines += [f"- ⚠ {u}" for u in ss.unpaired]
        return "\n".join(lines)
