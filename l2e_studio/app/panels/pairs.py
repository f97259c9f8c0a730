"""An initial guess from clicked pairs (a folder of the Seed tab): pick a lidar point in the 3D
view, then its pixel on the overlay; with four or more pairs, PnP (OpenCV) gives the seed.

The pairs live in an editable text field, one ``x y z u v`` line each (lidar metres, map
pixels), so they can be corrected, pasted, and saved with the seed.
"""

from __future__ import annotations

import numpy as np
import viser

from ..context import Workbench
from ..exact import parse_number
from ..pairs import MIN_PAIRS, Pair, nearest_point_to_ray, reprojection_errors, solve_pnp
from ..text import num

HELP = ("**Pick a pair**, click a lidar point in the 3D view, then the same spot on the overlay. "
        f"With {MIN_PAIRS} or more pairs, **Solve PnP** sets the extrinsic (one undo step). "
        "Lines `x y z u v` below can be edited.")


def parse_pairs(text: str) -> tuple[list[Pair], list[str]]:
    """The pairs in ``text`` (one ``x y z u v`` line each) and a problem per bad line."""
    pairs, problems = [], []
    for n, line in enumerate(str(text).splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        values = [parse_number(v) for v in line.replace(",", " ").split()]
        if len(values) != 5 or any(v is None for v in values):
            problems.append(f"line {n}: expected 5 numbers x y z u v, got “{line}”")
            continue
        x, y, z, u, v = (float(a) for a in values)  # type: ignore[arg-type]
        pairs.append(Pair((x, y, z), (u, v)))
    return pairs, problems


def format_pair(p: Pair) -> str:
    return " ".join(f"{a:.4f}" for a in p.point) + "  " + " ".join(f"{a:.1f}" for a in p.pixel)


class PairsPanel:
    def __init__(self, app: Workbench) -> None:
        self.app = app
        gui = app.server.gui
        with gui.add_folder("Initial guess from clicked pairs", expand_by_default=False):
            gui.add_markdown(HELP)
            self.pick = gui.add_button("Pick a pair", icon=viser.Icon.POINTER,
                                       hint="Then click a lidar point in the 3D view, then its pixel on the overlay")
            self.status = gui.add_markdown("")
            self.text = gui.add_text("Pairs", "", multiline=True, hint="x y z (lidar, m)  u v (map pixels)")
            self.table = gui.add_markdown("")
            self.edit = gui.add_button_group("Pairs ±", ("Remove last", "Clear"))
            self.solve = gui.add_button("Solve PnP", icon=viser.Icon.MATH_FUNCTION, disabled=True,
                                        hint=f"OpenCV solvePnP (SQPnP + refinement) over the pairs; needs {MIN_PAIRS}")
        self.pending: tuple[float, float, float] | None = None
        self.armed = False
        self._marker = None
        self.pick.on_click(lambda event: self.arm())
        self.text.on_update(lambda _: self.show())
        self.edit.on_click(lambda event: self._edit(self.edit.value))
        self.solve.on_click(self._on_solve)

    # --- picking -------------------------------------------------------------------------------
    def arm(self) -> None:
        """Wait for a click on a lidar point in the 3D view."""
        self.armed, self.pending = True, None
        self.status.content = "Click a lidar point in the **3D view**..."
        scene = self.app.server.scene
        scene.remove_click_callback()
        scene.on_click()(self._on_scene_click)

    def _on_scene_click(self, event) -> None:
        index = self.app.state.snapshot().selected
        points = self.app.displays[index].scene.points
        k = nearest_point_to_ray(points, event.ray_origin, event.ray_direction, max_angle_deg=1.0)
        if k is None:
            self.status.content = "No lidar point near that click; click closer to a point."
            return
        self.point_picked(tuple(float(a) for a in points[k]))

    def point_picked(self, point: tuple[float, float, float]) -> None:
        self.app.server.scene.remove_click_callback()
        self.pending = point
        self._marker = self.app.server.scene.add_icosphere("/pair_pick", radius=0.08, color=(255, 0, 200),
                                                           position=point)
        self.status.content = (f"Lidar point ({', '.join(f'{a:.3f}' for a in point)}) m. "
                               "Now click the same spot on the **overlay**.")

    def wants_pixel(self) -> bool:
        return self.armed and self.pending is not None

    def pixel_picked(self, x: float, y: float) -> None:
        """The overlay was clicked at map pixel (x, y): complete the pending pair."""
        assert self.pending is not None
        pair = Pair(self.pending, (float(x), float(y)))
        text = self.text.value.rstrip("\n")
        self.text.value = (text + "\n" if text else "") + format_pair(pair)
        self.armed, self.pending = False, None
        if self._marker is not None:
            self._marker.remove()
            self._marker = None
        self.status.content = "Pair added."
        self.show()

    # --- the list ------------------------------------------------------------------------------
    def pairs(self) -> list[Pair]:
        return parse_pairs(self.text.value)[0]

    def _edit(self, action: str) -> None:
        lines = [ln for ln in self.text.value.splitlines() if ln.strip()]
        self.text.value = "\n".join(lines[:-1] if action == "Remove last" else [])
        self.show()

    def show(self) -> None:
        """The pairs with their reprojection error at the current extrinsic."""
        pairs, problems = parse_pairs(self.text.value)
        self.solve.disabled = len(pairs) < MIN_PAIRS
        ext = self.app.state.snapshot().extrinsic
        errors = reprojection_errors(ext, pairs, self.app.camera)
        rows = []
        if pairs:
            rows = ["| # | lidar (m) | pixel | error now (px) |", "|--:|:--|:--|--:|"]
            for i, (p, e) in enumerate(zip(pairs, errors), 1):
                rows.append(f"| {i} | {', '.join(f'{a:.2f}' for a in p.point)} | "
                            f"{p.pixel[0]:.0f}, {p.pixel[1]:.0f} | {num(e, 1)} |")
        if len(pairs) < MIN_PAIRS:
            rows.append(f"{len(pairs)} of {MIN_PAIRS} pairs needed for PnP.")
        rows += [f"⚠ {p}" for p in problems]
        self.table.content = "\n".join(rows)

    def _on_solve(self, event) -> None:
        pairs = self.pairs()
        try:
            ext = solve_pnp(pairs, self.app.camera, self.app.state.snapshot().extrinsic)
        except (ValueError, Exception) as exc:  # OpenCV errors are cv2.error
            self.app.notify(event.client, "PnP failed", str(exc), color="red")
            return
        self.app.set_extrinsic(ext, source="pnp")
        errors = reprojection_errors(ext, pairs, self.app.camera)
        self.show()
        self.status.content = (f"PnP over {len(pairs)} pairs: reprojection error median "
                               f"{num(float(np.median(errors)), 2)} px, max {num(float(np.max(errors)), 2)} px.")
