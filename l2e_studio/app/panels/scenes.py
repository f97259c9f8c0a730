"""The scene list: pick the scene shown, include or exclude scenes from the optimisation,
see every scene's score at the current extrinsic and the scenes that failed to load."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import yaml

from ...errors import InputError
from ...io.safe_load import parse_yaml, read_text_capped
from ..browser_js import KEY_HANDLING_HTML, hide_inputs
from ..context import Workbench
from ..readout import MiReading
from ..text import score_num


SORT_KEYS = ("name", "points", "score now (high first)", "score now (low first)")
TABLE_MARK = "use"  # the first header cell: how the page script recognises this table's rows


def scene_order(key: str, names: Sequence[str], points: Sequence[int], mi: Sequence[float] | None) -> list[int]:
    """Scene indices in the table's order (score sorts put missing values last)."""
    idx = list(range(len(names)))
    if key == "points":
        return sorted(idx, key=lambda i: (-points[i], names[i]))
    if key.startswith("score") and mi is not None:
        sign = -1.0 if "high" in key else 1.0
        return sorted(idx, key=lambda i: (not np.isfinite(mi[i]), sign * float(np.nan_to_num(mi[i])), names[i]))
    return sorted(idx, key=lambda i: names[i])


def first_steps_hint(root: Path) -> str:
    """What to press first, for a synthetic set whose ``truth.yaml`` says how far off its seed is
    (the embedded sample, anything ``l2e-studio synth`` wrote); "" for any other folder."""
    path = Path(root) / "truth.yaml"
    try:
        err = parse_yaml(path, read_text_capped(path, 1 << 20)).get("seed_error") if path.is_file() else None
        deg, m = float(err["rotation_deg"]), float(err["translation_m"])
    except (InputError, OSError, yaml.YAMLError, ValueError, TypeError, KeyError, AttributeError):  # no hint, no harm
        return ""
    return (f"**First steps** · this synthetic set's seed is off on purpose, by {deg:.1f}° and {100 * m:.1f} cm "
            "(`truth.yaml`): the points sit beside the edges they belong to. Press **Start** in the "
            "**Optimise** tab, compare in **Before / after**, then accept the result in the **Result** tab.")


class ScenesPanel:
    def __init__(self, app: Workbench) -> None:
        self.app = app
        gui = app.server.gui
        ss = app.scene_set
        names = app.state.scene_names
        hint = first_steps_hint(ss.root)
        self.hint = gui.add_markdown(hint, visible=bool(hint))
        gui.add_markdown(f"**{len(names)} scenes** from `{ss.root}`"
                         + (f" · **{len(ss.failures)} failed to load**" if ss.failures else ""))
        self.dropdown = gui.add_dropdown("Scene", names, initial_value=names[0])
        self.include = gui.add_checkbox("Use in optimisation", True,
                                        hint="Excluded scenes are held out: still scored, not optimised over")
        self.all_on = gui.add_button_group("Include", ("all", "none"))
        self.sort = gui.add_dropdown("Sort by", SORT_KEYS, initial_value="name",
                                     hint="Order of the table; click a row to show that scene, its ✓ to include it")
        self.pointer = gui.add_text("Scene pointer", "", hint="(set by clicks on the table)")
        gui.add_html(hide_inputs([self.pointer]) + KEY_HANDLING_HTML)
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

        self.sort.on_update(lambda _: setattr(self.table, "content", self._table(self.app.reading)))
        self.pointer.on_update(self._on_row_click)

    def _on_row_click(self, event) -> None:
        """A click on a table row: ``select:<name>`` shows that scene, ``toggle:<name>`` flips its inclusion."""
        if event.client is None:
            return
        action, _, rest = str(self.pointer.value).partition(":")
        name = rest.rsplit(",", 1)[0].strip()
        names = self.app.state.scene_names
        if name not in names:
            return
        index = names.index(name)
        if action == "toggle":
            self.app.state.set_included(index, not self.app.state.snapshot().included[index])
            self.app.inclusion_changed()
        elif action == "select":
            self.app.select_scene(index)

    def show_selection(self, table: bool = True) -> None:
        """The selected scene in the dropdown and its include box (and in the table, ``table``)."""
        snap = self.app.state.snapshot()
        self.dropdown.value = self.app.state.scene_names[snap.selected]
        self.include.value = snap.included[snap.selected]
        if table:
            self.table.content = self._table(self.app.reading)

    def show_mi(self, reading: MiReading) -> None:
        self.table.content = self._table(reading)

    def _table(self, reading: MiReading | None) -> str:
        snap = self.app.state.snapshot()
        n_in = sum(snap.included)
        rows = [f"Optimising over **{n_in}** of {len(snap.included)} scenes.", "",
                f"| {TABLE_MARK} | scene | points | score now |", "|:-:|:--|--:|--:|"]
        for i in scene_order(self.sort.value, self.app.state.scene_names,
                             [s.points.shape[0] for s in self.app.scene_set.scenes],
                             None if reading is None else reading.per_scene):
            name = self.app.state.scene_names[i]
            mark = "✓" if snap.included[i] else "–"
            mi = "" if reading is None else score_num(reading.per_scene[i])
            label = f"**{name}**" if i == snap.selected else name
            rows.append(f"| {mark} | {label} | {self.app.scene_set.scenes[i].points.shape[0]} | {mi} |")
        return "\n".join(rows)

    def _failures(self) -> str:
        ss = self.app.scene_set
        lines = ["**Not loaded:**", ""]
        lines += [f"- ✗ `{f.name}`: {f.error}" for f in ss.failures]
        lines += [f"- ⚠ {u}" for u in ss.unpaired]
        return "\n".join(lines)
