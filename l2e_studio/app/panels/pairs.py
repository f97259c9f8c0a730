"""An initial guess from clicked pairs (a folder of the Seed tab): pick a lidar point in the 3D
view, then its pixel on the overlay; with four or more pairs, PnP (OpenCV) gives the seed.

Picking mode (Start picking ... Stop picking) looks through the camera in the 3D view, dims the
points the camera cannot see (only the others can be picked), widens the 3D view and arms the
next pick after each pair, so pair after pair is two clicks. Markers grow with their distance
from the camera, so they stay a few pixels wide at any range.

The pairs live in an editable text field, one ``x y z u v`` line each (lidar metres, map
pixels), so they can be corrected, pasted, and saved with the seed.
"""

from __future__ import annotations

import numpy as np
import viser

from ..context import Workbench
from ..exact import parse_number
from ..overlay import project_scene
from ..pairs import (MIN_PAIRS, Pair, nearest_point_to_ray, pair_spread, reprojection_errors, solve_pnp,
                     translation_warning)
from ..text import num

HELP = ("**Start picking**: the 3D view looks through the camera (points it cannot see are dimmed); "
        "click a lidar point there, then the same spot on the overlay, and again for the next pair. "
        f"With {MIN_PAIRS} or more pairs, **Solve PnP** sets the extrinsic (one undo step). "
        "Pick near and far points spread over the image: far-only pairs leave the translation loose. "
        "Lines `x y z u v` below can be edited.")
MARKER_RAD = 0.006  # marker radius per metre of distance from the camera (a few pixels at any range)
MIN_MARKER_M = 0.03
DEFAULT_BOUND_M = 0.2  # the optimiser's default translation bound, when the Optimise field holds none


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
            self.pick = gui.add_button("Start picking", icon=viser.Icon.POINTER,
                                       hint="Look through the camera in the 3D view; then click a lidar point "
                                            "there and its pixel on the overlay, pair after pair")
            self.status = gui.add_markdown("")
            self.text = gui.add_text("Pairs", "", multiline=True, hint="x y z (lidar, m)  u v (map pixels)")
            self.table = gui.add_markdown("")
            self.edit = gui.add_button_group("Pairs ±", ("Remove last", "Clear"))
            self.solve = gui.add_button("Solve PnP", icon=viser.Icon.MATH_FUNCTION, disabled=True,
                                        hint=f"OpenCV solvePnP (SQPnP + refinement) over the pairs; needs {MIN_PAIRS}")
        self.pending: tuple[float, float, float] | None = None
        self.armed = False
        self.picking = False
        self._marker = None
        self._pair_markers: list = []
        self._markers_for: tuple = ()
        self.pick.on_click(lambda event: self.set_picking(not self.picking))
        self.text.on_update(lambda _: self.show())
        self.edit.on_click(lambda event: self._edit(self.edit.value))
        self.solve.on_click(self._on_solve)

    # --- picking -------------------------------------------------------------------------------
    def set_picking(self, on: bool) -> None:
        """Enter or leave picking mode (the 3D view through the camera, a wider 3D view)."""
        self.picking = bool(on)
        self.pick.label = "Stop picking" if self.picking else "Start picking"
        self.pick.color = "orange" if self.picking else None
        self.app.picking_changed(self.picking)
        if self.picking:
            self.arm()
        else:
            self.app.server.scene.remove_click_callback()
            self.armed, self.pending = False, None
            self._remove_marker()
            self.status.content = ""
        self.show()

    def arm(self) -> None:
        """Wait for a click on a lidar point in the 3D view."""
        self.armed, self.pending = True, None
        self.status.content = f"Pair {len(self.pairs()) + 1}: click a lidar point in the **3D view**..."
        scene = self.app.server.scene
        scene.remove_click_callback()
        scene.on_click()(self._on_scene_click)

    def _on_scene_click(self, event) -> None:
        snap = self.app.state.snapshot()
        points = self.app.displays[snap.selected].scene.points
        k = nearest_point_to_ray(points, event.ray_origin, event.ray_direction, max_angle_deg=1.0)
        if k is None:
            self.status.content = "No lidar point near that click; click closer to a point."
            return
        self.point_picked(tuple(float(a) for a in points[k]))

    def marker_radius(self, point) -> float:
        """Metres: a fixed angle seen from the camera, so a marker 40 m away is as visible as one at 4 m."""
        centre = self.app.state.snapshot().extrinsic.inverse().translation
        return max(MIN_MARKER_M, MARKER_RAD * float(np.linalg.norm(np.asarray(point) - centre)))

    def point_picked(self, point: tuple[float, float, float]) -> None:
        self.app.server.scene.remove_click_callback()
        self.pending = point
        self._remove_marker()
        self._marker = self._markers("/pair_pick", [point], (255, 0, 200))
        seen = project_scene(np.asarray([point]), self.app.state.snapshot().extrinsic, self.app.camera).index.size
        self.status.content = (f"Lidar point ({', '.join(f'{a:.3f}' for a in point)}) m. "
                               "Now click the same spot on the **overlay**."
                               + ("" if seen else "  \n⚠ At the current extrinsic the camera does not see this "
                                  "point (a dimmed one): is it the one you meant? Stop picking removes it."))

    def _markers(self, name: str, points: list, colour: tuple[int, int, int]):
        """Markers drawn as one point cloud of fat points (the lidar cloud's kind of node: a mesh
        would cost a browser without a GPU up to a minute compiling its shader), each as wide as
        :meth:`marker_radius` says for the farthest one."""
        pts = np.asarray(points, np.float32).reshape(-1, 3)
        size = 2.0 * max(self.marker_radius(p) for p in pts)
        return self.app.server.scene.add_point_cloud(name, pts, np.tile(np.array(colour, np.uint8), (len(pts), 1)),
                                                     point_size=size, point_shape="circle", point_shading="flat")

    def _remove_marker(self) -> None:
        if self._marker is not None:
            self._marker.remove()
            self._marker = None

    def wants_pixel(self) -> bool:
        return self.armed and self.pending is not None

    def pixel_picked(self, x: float, y: float) -> None:
        """The overlay was clicked at map pixel (x, y): complete the pending pair."""
        assert self.pending is not None
        pair = Pair(self.pending, (float(x), float(y)))
        text = self.text.value.rstrip("\n")
        self.text.value = (text + "\n" if text else "") + format_pair(pair)
        self.armed, self.pending = False, None
        self._remove_marker()
        self.show()
        if self.picking:
            self.arm()  # straight on to the next pair: no button to press again
            self.status.content = "Pair added. " + self.status.content
        else:
            self.status.content = "Pair added."

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
        self._show_pair_markers(pairs)

    def _show_pair_markers(self, pairs: list[Pair]) -> None:
        """A green marker on each pair's lidar point while picking (none otherwise)."""
        key = (self.picking, tuple(p.point for p in pairs))
        if key == self._markers_for:  # show() runs on every extrinsic change
            return
        self._markers_for = key
        for m in self._pair_markers:
            m.remove()
        self._pair_markers = []
        if self.picking and pairs:
            self._pair_markers.append(self._markers("/pairs", [p.point for p in pairs], (40, 220, 90)))

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
        warning = translation_warning(pair_spread(ext, pairs, self.app.camera), self._loose_limit())
        if warning:
            self.status.content += f"  \n⚠ {warning}"
            self.app.notify(event.client, "The translation is not pinned", warning, color="yellow")

    def _loose_limit(self) -> float:
        """m, 1 sigma: a third of the optimiser's translation bound, so that the optimiser's search
        (seed ± bound) holds the truth with 3-sigma margin."""
        try:
            bound = self.app.run_settings().translation_bound
        except ValueError:
            bound = DEFAULT_BOUND_M
        return (bound if bound > 0 else DEFAULT_BOUND_M) / 3.0
