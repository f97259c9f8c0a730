"""The result of the last run: MI at seed and at result (pooled and per scene), accept it as
the new seed or discard it, and save the result file with a before/after image."""

from __future__ import annotations

from typing import TYPE_CHECKING

import viser

from ...errors import InputError
from ..pose import describe
from ..state import Snapshot

if TYPE_CHECKING:
    from ..server import App

NO_RESULT = "No result yet."


class ResultPanel:
    def __init__(self, app: "App") -> None:
        self.app = app
        gui = app.server.gui
        self.summary = gui.add_markdown(NO_RESULT)
        self.accept = gui.add_button("Accept as seed", color="green", icon=viser.Icon.CHECK, disabled=True,
                                     hint="Make the result the current extrinsic (the next run starts there)")
        self.discard = gui.add_button("Discard", icon=viser.Icon.TRASH, disabled=True)
        self.save = gui.add_button("Save result", icon=viser.Icon.DEVICE_FLOPPY, disabled=True,
                                   hint=f"Write a result file and a before/after PNG into {app.out_dir}")
        self.saved = gui.add_markdown("")
        self.table = gui.add_markdown("")
        self.accept.on_click(self._accept)
        self.discard.on_click(lambda event: app.discard_result())
        self.save.on_click(self._on_save)

    def _accept(self, event) -> None:
        self.app.accept_result()
        self.app.notify(event.client, "Result accepted", "The sliders now show the result; Start again to refine.",
                        color="green")

    def _on_save(self, event) -> None:
        try:
            path, png = self.app.save_result()
        except (InputError, OSError, RuntimeError) as exc:
            self.app.notify(event.client, "Result not saved", str(exc), color="red")
            return
        body = f"{path}" + (f" and {png}" if png else "")
        self.saved.content = f"Saved `{path}`" + (f"  \nand `{png}`" if png else "")
        self.app.notify(event.client, "Result saved", body, color="green")

    def show(self, snap: Snapshot) -> None:
        r = snap.result
        has = r is not None
        self.accept.disabled = not has
        self.discard.disabled = not has
        self.save.disabled = not has
        if not has:
            self.summary.content = NO_RESULT
            self.table.content = ""
            return
        err_deg, err_m = r.seed.error_to(r.extrinsic)
        state = "cancelled (best point so far)" if r.cancelled else "finished"
        self.summary.content = (
            f"**Run {state}** · {r.settings.method} · {r.evaluations} evaluations · {r.seconds:.1f} s  \n"
            f"**MI {r.score_seed:.4f} → {r.score_result:.4f}** ({r.score_result - r.score_seed:+.4f}) over "
            f"{len(r.scene_names)} scenes  \n"
            f"moved {err_deg:.3f}° / {100 * err_m:.2f} cm from its seed  \n"
            f"{describe(r.extrinsic, self.app.state.reference)}"
        )
        rows = ["| scene | MI seed | MI result | Δ |", "|:--|--:|--:|--:|"]
        for name, a, b in zip(r.scene_names, r.score_seed_per_scene, r.score_result_per_scene):
            rows.append(f"| {name} | {a:.4f} | {b:.4f} | {b - a:+.4f} |")
        self.table.content = "\n".join(rows)
