"""The 3D view: the selected scene's lidar cloud (lidar frame = world), the camera frustum at
the current extrinsic showing the event map, and a transform gizmo on the camera that edits
the same extrinsic as the sliders."""

from __future__ import annotations

import numpy as np
import viser
from scipy.spatial.transform import Rotation

from ..context import Workbench
from ...camera import CameraModel
from ...geometry import Extrinsic
from ..overlay import project_scene

FRUSTUM_SCALE = 0.6  # m
GIZMO_SCALE = 0.9
DIMMED = 0.25  # brightness of the points the camera cannot see, while picking
#: m: the near plane while looking through the camera. Points right at the eye would be drawn
#: as sprites covering the view (and cost a browser without a GPU seconds per frame).
PICKING_NEAR_M = 0.5
#: deg: the widest vertical view while looking through the camera (a wide camera's edges are
#: cut off in a narrow viewport rather than the view distorted, which also stalls the page's renderer)
MAX_FOV_DEG = 100.0


def camera_pose(extrinsic: Extrinsic) -> tuple[np.ndarray, np.ndarray]:
    """(wxyz, position) of the camera in the lidar frame, i.e. ``T_lidar_cam``."""
    inv = extrinsic.inverse()
    x, y, z, w = inv.quaternion_xyzw
    return np.array([w, x, y, z]), inv.translation


def extrinsic_from_pose(wxyz: np.ndarray, position: np.ndarray) -> Extrinsic:
    """``T_cam_lidar`` from the camera's pose in the lidar frame."""
    w, x, y, z = np.asarray(wxyz, dtype=np.float64)
    return Extrinsic.from_quaternion([x, y, z, w], position).inverse()


FINE_FACTOR = 0.1


def camera_viewpoint(extrinsic: Extrinsic, camera: CameraModel, aspect: float) -> dict:
    """Where a 3D viewer looks through the camera at ``extrinsic``: position, look-at point, up
    direction (the image's up, in the lidar frame) and a vertical field of view wide enough to
    show the whole image in a viewport ``aspect`` (width / height) wide, up to ``MAX_FOV_DEG``."""
    inv = extrinsic.inverse()
    pos, R = inv.translation, inv.R  # camera centre and axes (x right, y down, z forward) in the lidar frame
    v_half = np.arctan2(camera.height / 2.0, camera.K[1, 1])
    h_half = np.arctan2(camera.width / 2.0, camera.K[0, 0])
    fov = 2.0 * max(v_half, np.arctan(np.tan(h_half) / max(float(aspect), 1e-3)))
    return {"position": pos, "look_at": pos + 10.0 * R[:, 2], "up": -R[:, 1], "fov": float(min(fov, np.radians(MAX_FOV_DEG)))}


def in_view_colors(points: np.ndarray, colors: np.ndarray, extrinsic: Extrinsic, camera: CameraModel) -> np.ndarray:
    """``colors`` with every point the camera cannot see at ``extrinsic`` dimmed to a quarter."""
    seen = np.zeros(len(points), bool)
    seen[project_scene(points, extrinsic, camera).index] = True
    out = (colors.astype(np.float32) * DIMMED).astype(np.uint8)
    out[seen] = colors[seen]
    return out


def scaled_gizmo_step(current: Extrinsic, before: tuple, after: tuple, factor: float) -> Extrinsic:
    """``current`` moved by ``factor`` times the gizmo's step from pose ``before`` to ``after``
    ((wxyz, position) of the camera in the lidar frame; the step is taken in the lidar frame)."""
    (w0, p0), (w1, p1) = before, after
    r0 = Rotation.from_quat([w0[1], w0[2], w0[3], w0[0]])
    r1 = Rotation.from_quat([w1[1], w1[2], w1[3], w1[0]])
    step = Rotation.from_rotvec(factor * (r1 * r0.inv()).as_rotvec())
    cw, cp = camera_pose(current)
    rc = Rotation.from_quat([cw[1], cw[2], cw[3], cw[0]])
    x, y, z, w = (step * rc).as_quat()
    return extrinsic_from_pose(np.array([w, x, y, z]), cp + factor * (np.asarray(p1) - np.asarray(p0)))


class View3D:
    def __init__(self, app: Workbench) -> None:
        self.app = app
        scene = app.server.scene
        cam = app.camera
        scene.set_up_direction("+z")  # lidar frames are z-up
        points, colors = app.displays[0].cloud()
        self.cloud = scene.add_point_cloud("/lidar", points, colors, point_size=0.04, point_shape="circle",
                                           point_shading="flat")
        wxyz, pos = camera_pose(app.state.reference)
        self.gizmo = scene.add_transform_controls("/camera", scale=GIZMO_SCALE, wxyz=wxyz, position=pos,
                                                  depth_test=False, opacity=0.8)
        fov = 2.0 * np.arctan2(cam.height / 2.0, cam.K[1, 1])
        self.frustum = scene.add_camera_frustum(
            "/camera/frustum", fov=float(fov), aspect=cam.width / cam.height, scale=FRUSTUM_SCALE,
            image=app.displays[0].thumbnail(), format="jpeg", color=(230, 80, 20),
        )
        self.shown_scene = 0
        self.gizmo.on_update(self._on_gizmo)
        self._place_viewer(app.state.reference, points)
        self.reset_view = app.server.gui.add_button(
            "Reset 3D view", icon=viser.Icon.HOME, hint="Put the 3D view back behind the camera, looking along it")
        self.reset_view.on_click(lambda event: self.reset_viewpoint())
        self.fine = app.server.gui.add_checkbox(
            "Fine gizmo (1/10)", False, hint="A gizmo drag moves the camera a tenth as far (it catches up when you let go)")
        self._last_pose = (np.asarray(wxyz, float), np.asarray(pos, float))  # the gizmo pose last seen
        self.picking = False

    # --- picking mode (pairs for PnP) ------------------------------------------------------------
    def set_picking(self, on: bool) -> None:
        """Picking: every tab looks through the camera at the current extrinsic, the points it
        can see keep their colours and the others are dimmed; the gizmo and frustum (which sit
        at the eye) are hidden. Off: all back as it was."""
        self.picking = bool(on)
        self.gizmo.visible = self.frustum.visible = not self.picking
        self._colour_cloud()
        if self.picking:
            self.look_through_camera()
        else:
            self.reset_viewpoint()

    def look_through_camera(self) -> None:
        ext = self.app.state.snapshot().extrinsic
        for client in self.app.server.get_clients().values():
            try:
                view = camera_viewpoint(ext, self.app.camera, client.camera.aspect or 1.6)
                client.camera.fov = view["fov"]
                client.camera.near = PICKING_NEAR_M
                client.camera.up_direction = tuple(view["up"])
                client.camera.position = tuple(view["position"])
                client.camera.look_at = tuple(view["look_at"])
            except Exception:  # a tab closing right now
                continue

    def _colour_cloud(self) -> None:
        points, colors = self.app.displays[self.shown_scene].cloud()
        if self.picking:
            colors = in_view_colors(points, colors, self.app.state.snapshot().extrinsic, self.app.camera)
        self.cloud.colors = colors

    def reset_viewpoint(self) -> None:
        """Every tab's 3D viewpoint back to the start-up one."""
        ic = self.app.server.initial_camera
        for client in self.app.server.get_clients().values():
            try:
                client.camera.fov = ic.fov
                client.camera.near = ic.near
                client.camera.up_direction = ic.up
                client.camera.position = ic.position
                client.camera.look_at = ic.look_at
            except Exception:  # a tab closing right now
                continue

    def _place_viewer(self, extrinsic: Extrinsic, points: np.ndarray) -> None:
        """Start the browser's viewpoint behind and above the camera, looking along it."""
        wxyz, pos = camera_pose(extrinsic)
        forward = extrinsic.inverse().R[:, 2]
        depth = float(np.median(np.linalg.norm(points, axis=1))) if len(points) else 5.0
        ic = self.app.server.initial_camera
        ic.position = tuple(pos - 0.6 * depth * forward + np.array([0.0, 0.0, 0.35 * depth]))
        ic.look_at = tuple(pos + 0.5 * depth * forward)
        ic.up = (0.0, 0.0, 1.0)

    def _on_gizmo(self, event) -> None:
        wxyz, pos = np.asarray(self.gizmo.wxyz, float), np.asarray(self.gizmo.position, float)
        previous, self._last_pose = self._last_pose, (wxyz, pos)
        if not self.fine.value:
            self.app.set_extrinsic(extrinsic_from_pose(wxyz, pos), source="gizmo")
            return
        current = self.app.state.snapshot().extrinsic
        ext = scaled_gizmo_step(current, previous, (wxyz, pos), FINE_FACTOR)
        self.app.set_extrinsic(ext, source="gizmo-fine")  # the gizmo is re-posed when the drag rests

    def show_pose(self, extrinsic: Extrinsic) -> None:
        wxyz, pos = camera_pose(extrinsic)
        self.gizmo.wxyz = wxyz
        self.gizmo.position = pos
        self._last_pose = (np.asarray(wxyz, float), np.asarray(pos, float))
        if self.picking:
            self._colour_cloud()  # what the camera sees moves with it

    def show_scene(self, index: int) -> None:
        if index == self.shown_scene:
            return
        disp = self.app.displays[index]
        points, colors = disp.cloud()
        self.cloud.points = points.astype(np.float32)
        self.shown_scene = index
        self._colour_cloud()
        self.frustum.image = disp.thumbnail()

    def show_map(self, index: int) -> None:
        """Scene ``index``'s map changed: redraw the camera's thumbnail if it shows that scene."""
        if index == self.shown_scene:
            self.frustum.image = self.app.displays[index].thumbnail()
