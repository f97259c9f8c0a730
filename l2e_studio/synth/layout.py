"""Random layouts of an underground garage, the place the L2E paper recorded its scenes.

A garage is a room (floor with parking bays, lane markings, arrows and stains; walls with a
painted band, signs and lettering; ceiling with light strips and pipes), a grid of pillars with
hazard stripes, parked cars, and near the sensor rig a few objects that make translation
observable: crates, sign stands, bollards and, in "checkerboard scenes", calibration targets on
stands. Every choice comes from the generator passed in, so a layout is reproducible.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .world import Box, Decal, random_waves

RETRO = (1.15, 1.45)  # reflectance range of retro-reflective material (see world.py)


@dataclass
class Layout:
    """A world and where the lidar stands in it: ``X_world = lidar_R @ X_lidar + lidar_pos``."""

    boxes: list[Box]
    lidar_R: np.ndarray
    lidar_pos: np.ndarray
    checkerboard: bool


def rot(yaw: float = 0.0, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (radians)."""
    return Rotation.from_euler("xyz", [roll, pitch, yaw]).as_matrix()


def make_layout(
    rng: np.random.Generator,
    checkerboard: bool,
    view_half_angle: float = np.radians(27.0),
    clearance: float = 0.8,
) -> Layout:
    """A random garage and rig pose; objects are kept ``clearance`` m away from the rig.

    ``view_half_angle`` is the half-width (rad) of the sector in front of the rig where the near
    objects go, so that the camera sees them.
    """
    L, W, H = rng.uniform(30, 60), rng.uniform(18, 32), rng.uniform(2.6, 3.4)
    h = rng.uniform(0.9, 1.5)
    pos = np.array([rng.uniform(-L / 2 + 4, L / 2 - 4), rng.uniform(-W / 2 + 4, W / 2 - 4), h])
    yaw = rng.uniform(-np.pi, np.pi)
    lidar_R = rot(yaw, np.radians(rng.uniform(-2, 2)), np.radians(rng.uniform(-2, 2)))

    boxes = [_room(rng, L, W, H, pos)]
    boxes += _pillars(rng, L, W, H)
    boxes += _pipes(rng, L, W, H)
    boxes += _cars(rng, pos, yaw, L, W)
    near = []
    if checkerboard:
        for _ in range(rng.integers(1, 3)):
            near += _checkerboard(rng, pos, yaw, view_half_angle * 0.8)
    for _ in range(rng.integers(3, 6)):
        kind = rng.choice(["crates", "sign", "bollard", "crates"])
        place = _place(rng, pos, yaw, view_half_angle, 2.0, 8.0)
        near += {"crates": _crates, "sign": _sign_stand, "bollard": _bollard}[kind](rng, place, pos)
    boxes += near
    keep = [boxes[0]] + [b for b in boxes[1:] if not b.contains(pos, clearance)]
    return Layout(keep, lidar_R, pos, checkerboard)


# --- helpers ------------------------------------------------------------------------------------


def _place(rng, pos, yaw, half_angle, r_min, r_max) -> np.ndarray:
    """A floor point (x, y, 0) at a random bearing/distance in the sector ahead of the rig."""
    a = yaw + rng.uniform(-half_angle, half_angle)
    r = rng.uniform(r_min, r_max)
    return np.array([pos[0] + r * np.cos(a), pos[1] + r * np.sin(a), 0.0])


def _facing(point, pos) -> float:
    """Yaw that turns a local +x axis at ``point`` towards the rig."""
    return float(np.arctan2(pos[1] - point[1], pos[0] - point[0]))


def _paint(rng, lo=0.15, hi=0.8) -> float:
    return float(rng.uniform(lo, hi))


def _retro(rng) -> float:
    return float(rng.uniform(*RETRO))


def _upright(center, half, yaw, base, rng, grain=0.04, decals=None) -> Box:
    return Box(center, rot(yaw), half, base, grain, decals or [], waves=random_waves(rng))


# --- the room ------------------------------------------------------------------------------------


def _room(rng, L, W, H, pos) -> Box:
    floor, ceil = (2, -1), (2, 1)
    z_floor = -H / 2
    decals: list[Decal] = [
        Decal(floor, "rect", (0, 0), (L / 2, W / 2), _paint(rng, 0.15, 0.3)),
        Decal(ceil, "rect", (0, 0), (L / 2, W / 2), _paint(rng, 0.25, 0.45)),
    ]
    # parking bays along both long walls: lines every ~2.5 m, 5 m long
    bay = rng.uniform(2.4, 2.7)
    line = _paint(rng, 0.65, 0.85)
    for side in (-1, 1):
        y = side * (W / 2 - 2.6)
        decals.append(Decal(floor, "stripes", (0, y), (L / 2, 2.5), line, period=bay, duty=0.12 / bay))
        decals.append(Decal(floor, "rect", (0, side * (W / 2 - 5.15)), (L / 2, 0.06), line))
    # dashed lane line, a zebra crossing, arrows and stains near the rig
    decals.append(Decal(floor, "stripes", (0, rng.uniform(-1, 1)), (L / 2, 0.07), line, period=6.0, duty=0.5))
    cx, cy = pos[0] + rng.uniform(-6, 6), pos[1] + rng.uniform(-6, 6)
    decals.append(Decal(floor, "stripes", (cx, cy), (1.8, 2.5), line, angle=rng.uniform(0, np.pi), period=0.9, duty=0.5))
    for _ in range(rng.integers(3, 7)):
        ax, ay = pos[0] + rng.uniform(-14, 14), pos[1] + rng.uniform(-10, 10)
        ang = rng.integers(0, 4) * np.pi / 2 + rng.uniform(-0.1, 0.1)
        c, s = np.cos(ang), np.sin(ang)
        decals.append(Decal(floor, "rect", (ax, ay), (0.12, 1.0), line, angle=ang))
        decals.append(Decal(floor, "triangle", (ax - 1.3 * s, ay + 1.3 * c), (0.5, 0.45), line, angle=ang))
    for _ in range(rng.integers(4, 10)):
        decals.append(Decal(floor, "disc", (pos[0] + rng.uniform(-12, 12), pos[1] + rng.uniform(-12, 12)),
                            (rng.uniform(0.2, 0.7), 0), rng.uniform(0.04, 0.1)))
    # ceiling light strips
    for y in np.arange(-W / 2 + rng.uniform(2, 5), W / 2, rng.uniform(4, 7)):
        decals.append(Decal(ceil, "stripes", (rng.uniform(0, 3), y), (L / 2, 0.12), 0.9, period=rng.uniform(4, 7), duty=0.25))
    # walls: a painted band, a thin line, signs and lettering
    band_h = rng.uniform(0.8, 1.3)
    band = _paint(rng, 0.45, 0.85) if rng.random() < 0.6 else _paint(rng, 0.05, 0.15)
    wall_base = _paint(rng, 0.3, 0.55)
    for axis, length in ((0, W), (1, L)):
        for sign in (-1, 1):
            face = (axis, sign)
            decals.append(Decal(face, "rect", (0, 0), (length / 2, H / 2), wall_base))
            decals.append(Decal(face, "rect", (0, z_floor + band_h / 2), (length / 2, band_h / 2), band))
            decals.append(Decal(face, "rect", (0, z_floor + band_h + 0.25), (length / 2, 0.05), _paint(rng, 0.6, 0.9)))
            for u in np.arange(-length / 2 + rng.uniform(1, 5), length / 2 - 1, rng.uniform(5, 9)):
                decals += _wall_sign(rng, face, u, z_floor + rng.uniform(1.7, 2.2))
    return Box((0, 0, H / 2), np.eye(3), (L / 2, W / 2, H / 2), wall_base, 0.05, decals, inside=True,
               waves=random_waves(rng, 5, (1.0, 6.0)))


def _wall_sign(rng, face, u, v) -> list[Decal]:
    kind = rng.integers(0, 4)
    if kind == 0:  # exit-style retro panel with a dark pictogram
        return [Decal(face, "rect", (u, v), (0.35, 0.15), _retro(rng)),
                Decal(face, "rect", (u - 0.15, v), (0.05, 0.1), 0.08, angle=0.4)]
    if kind == 1:  # round prohibition sign: red ring, white inside
        r = rng.uniform(0.2, 0.35)
        return [Decal(face, "ring", (u, v), (r, 0.75 * r), _retro(rng), rho2=0.85)]
    if kind == 2:  # warning triangle
        return [Decal(face, "triangle", (u, v), (0.35, 0.3), _retro(rng)),
                Decal(face, "triangle", (u, v - 0.04), (0.22, 0.18), 0.8)]
    # lettering: a row of short bars
    return [Decal(face, "stripes", (u, v), (rng.uniform(0.4, 1.0), 0.12), 0.06, period=rng.uniform(0.06, 0.12), duty=0.45)]


# --- structure -------------------------------------------------------------------------------------


def _pillars(rng, L, W, H) -> list[Box]:
    sx, sy = rng.uniform(7.5, 9.5), rng.uniform(5.5, 8.0)
    w = rng.uniform(0.45, 0.8)
    base = _paint(rng, 0.35, 0.55)
    hazard = rng.random() < 0.7
    boxes = []
    for x in np.arange(-L / 2 + rng.uniform(3, sx), L / 2 - 2, sx):
        for y in np.arange(-W / 2 + rng.uniform(6, 6 + sy), W / 2 - 6, sy):
            band = rng.uniform(0.9, 1.5)
            decals = []
            for face in ((0, -1), (0, 1), (1, -1), (1, 1)):
                if hazard:
                    decals.append(Decal(face, "stripes", (0, -H / 2 + band / 2), (w / 2, band / 2), 0.7, rho2=0.06,
                                        period=0.22, duty=0.5, pattern_angle=np.pi / 4))
                else:
                    decals.append(Decal(face, "rect", (0, -H / 2 + band / 2), (w / 2, band / 2), _paint(rng, 0.05, 0.9)))
                decals.append(Decal(face, "rect", (0, -H / 2 + band + 0.9), (w / 2, 0.08), 0.85))
            face = [(0, -1), (0, 1), (1, -1), (1, 1)][rng.integers(0, 4)]
            decals.append(Decal(face, "disc", (0, -H / 2 + band + 0.45), (0.18, 0), _retro(rng)))
            boxes.append(_upright((x, y, H / 2), (w / 2, w / 2, H / 2), 0.0, base, rng, 0.05, decals))
    return boxes


def _pipes(rng, L, W, H) -> list[Box]:
    boxes = []
    for _ in range(rng.integers(2, 5)):
        r = rng.uniform(0.06, 0.15)
        z = H - rng.uniform(0.15, 0.5)
        if rng.random() < 0.5:
            boxes.append(_upright((0, rng.uniform(-W / 2, W / 2), z), (L / 2, r, r), 0.0, _paint(rng, 0.2, 0.8), rng, 0.02))
        else:
            boxes.append(_upright((rng.uniform(-L / 2, L / 2), 0, z), (r, W / 2, r), 0.0, _paint(rng, 0.2, 0.8), rng, 0.02))
    return boxes


# --- parked cars --------------------------------------------------------------------------------------


def _cars(rng, pos, yaw, L, W) -> list[Box]:
    boxes = []
    for _ in range(rng.integers(3, 9)):
        in_view = rng.random() < 0.6
        a = yaw + (rng.uniform(-0.6, 0.6) if in_view else rng.uniform(-np.pi, np.pi))
        r = rng.uniform(4.0, 16.0)
        c = np.array([pos[0] + r * np.cos(a), pos[1] + r * np.sin(a)])
        if abs(c[0]) > L / 2 - 3 or abs(c[1]) > W / 2 - 2:
            continue
        heading = rng.integers(0, 4) * np.pi / 2 + rng.uniform(-0.15, 0.15)
        boxes += _car(rng, c, heading)
    return boxes


def _car(rng, c, heading) -> list[Box]:
    length, width = rng.uniform(4.0, 4.8), rng.uniform(1.7, 1.9)
    z0, body_h = 0.18, rng.uniform(0.6, 0.8)
    paint = float(rng.choice([rng.uniform(0.05, 0.15), rng.uniform(0.3, 0.8)]))
    hb = (length / 2, width / 2, body_h / 2)
    wheel_z = -body_h / 2 + 0.12
    decals = [
        Decal((0, 1), "rect", (0, -0.05), (0.26, 0.06), _retro(rng)),  # front plate
        Decal((0, -1), "rect", (0, -0.05), (0.26, 0.06), _retro(rng)),  # rear plate
        Decal((0, 1), "rect", (-0.6, 0.12), (0.16, 0.06), 0.9),
        Decal((0, 1), "rect", (0.6, 0.12), (0.16, 0.06), 0.9),
        Decal((0, -1), "rect", (-0.65, 0.12), (0.14, 0.07), _retro(rng)),
        Decal((0, -1), "rect", (0.65, 0.12), (0.14, 0.07), _retro(rng)),
        Decal((0, 1), "stripes", (0, -0.22), (0.5, 0.08), 0.05, period=0.05, duty=0.5),  # grille
    ]
    for side in (-1, 1):
        for x in (-0.32 * length, 0.32 * length):
            decals.append(Decal((1, side), "ring", (x, wheel_z), (0.31, 0.17), 0.04, rho2=_paint(rng, 0.4, 0.7)))
        decals.append(Decal((1, side), "rect", (0, body_h / 2 - 0.1), (length * 0.45, 0.02), 0.7))  # trim
    body = Box((c[0], c[1], z0 + body_h / 2), rot(heading), hb, paint, 0.03, decals, waves=random_waves(rng))
    cab_h, cab_l = rng.uniform(0.4, 0.55), length * rng.uniform(0.45, 0.6)
    glass = rng.uniform(0.03, 0.08)
    cab_decals = [
        Decal((0, 1), "rect", (0, 0), (width / 2 - 0.1, cab_h / 2 - 0.05), glass),
        Decal((0, -1), "rect", (0, 0), (width / 2 - 0.1, cab_h / 2 - 0.05), glass),
        Decal((1, -1), "rect", (-cab_l * 0.22, 0), (cab_l * 0.22 - 0.06, cab_h / 2 - 0.06), glass),
        Decal((1, -1), "rect", (cab_l * 0.22, 0), (cab_l * 0.22 - 0.06, cab_h / 2 - 0.06), glass),
        Decal((1, 1), "rect", (-cab_l * 0.22, 0), (cab_l * 0.22 - 0.06, cab_h / 2 - 0.06), glass),
        Decal((1, 1), "rect", (cab_l * 0.22, 0), (cab_l * 0.22 - 0.06, cab_h / 2 - 0.06), glass),
    ]
    R = rot(heading)
    cab_c = np.array([c[0], c[1], z0 + body_h + cab_h / 2]) + R @ np.array([-0.08 * length, 0, 0])
    cab = Box(cab_c, R, (cab_l / 2, width / 2 - 0.08, cab_h / 2), paint, 0.03, cab_decals, waves=random_waves(rng))
    return [body, cab]


# --- near objects -----------------------------------------------------------------------------------------


def _checkerboard(rng, pos, yaw, half_angle) -> list[Box]:
    """A planar target on a pole, roughly facing the rig, at lidar height, 2-5 m away."""
    p = _place(rng, pos, yaw, half_angle, 2.0, 5.0)
    sq = rng.uniform(0.08, 0.12)
    nx, ny = int(rng.integers(7, 11)), int(rng.integers(5, 8))
    border = 0.05
    hw, hh = nx * sq / 2 + border, ny * sq / 2 + border
    zc = pos[2] + rng.uniform(-0.25, 0.25)
    R = rot(_facing(p, pos) + np.radians(rng.uniform(-35, 35)), np.radians(rng.uniform(-20, 20)),
            np.radians(rng.uniform(-30, 30)))
    white, black = rng.uniform(0.75, 0.9), rng.uniform(0.03, 0.07)
    decals = [
        Decal((0, 1), "checker", (0, 0), (nx * sq / 2, ny * sq / 2), white, rho2=black, period=sq),
        Decal((0, -1), "rect", (0, 0), (hw, hh), 0.3),
    ]
    board = Box((p[0], p[1], zc), R, (0.012, hw, hh), white, 0.01, decals, waves=random_waves(rng))
    pole_top = zc - hh * 0.8
    pole = _upright((p[0], p[1], pole_top / 2), (0.025, 0.025, max(pole_top / 2, 0.05)), 0.0, 0.2, rng, 0.0)
    return [board, pole]


def _crates(rng, place, pos) -> list[Box]:
    """One to three stacked boxes with tape and labels."""
    boxes = []
    z = 0.0
    yaw = rng.uniform(-np.pi, np.pi)
    for _ in range(rng.integers(1, 4)):
        hx, hy, hz = rng.uniform(0.2, 0.55), rng.uniform(0.2, 0.55), rng.uniform(0.15, 0.4)
        cardboard = _paint(rng, 0.25, 0.55)
        decals = [Decal(None, "rect", (0, 0), (0.03, 2.0), _paint(rng, 0.6, 0.9))]  # tape
        for face in ((0, 1), (0, -1), (1, 1), (1, -1)):
            if rng.random() < 0.5:
                kind = rng.integers(0, 3)
                cu, cv = rng.uniform(-0.08, 0.08), rng.uniform(-hz * 0.4, hz * 0.4)
                if kind == 0:
                    decals.append(Decal(face, "rect", (cu, cv), (0.1, 0.07), 0.9, angle=rng.uniform(-0.5, 0.5)))
                elif kind == 1:
                    decals.append(Decal(face, "stripes", (cu, cv), (0.1, 0.05), 0.04, period=0.015, duty=0.5))
                else:
                    decals.append(Decal(face, "triangle", (cu, cv), (0.12, 0.1), _retro(rng)))
        boxes.append(_upright((place[0], place[1], z + hz), (hx, hy, hz), yaw + rng.uniform(-0.3, 0.3), cardboard, rng, 0.04, decals))
        z += 2 * hz
    return boxes


def _sign_stand(rng, place, pos) -> list[Box]:
    """A traffic sign on a pole, plate roughly facing the rig."""
    top = pos[2] + rng.uniform(-0.4, 0.5)
    s = rng.uniform(0.25, 0.4)
    R = rot(_facing(place, pos) + np.radians(rng.uniform(-30, 30)))
    kind = rng.integers(0, 3)
    if kind == 0:
        decals = [Decal((0, 1), "ring", (0, 0), (s, 0.78 * s), _retro(rng), rho2=0.85),
                  Decal((0, 1), "rect", (0, 0), (0.6 * s, 0.12 * s), 0.06)]
    elif kind == 1:
        decals = [Decal((0, 1), "triangle", (0, -0.1 * s), (s, 0.9 * s), _retro(rng)),
                  Decal((0, 1), "triangle", (0, -0.13 * s), (0.65 * s, 0.58 * s), 0.85),
                  Decal((0, 1), "rect", (0, -0.2 * s), (0.05 * s, 0.25 * s), 0.06)]
    else:
        decals = [Decal((0, 1), "rect", (0, 0), (s, s), _retro(rng)),
                  Decal((0, 1), "rect", (0, 0), (0.15 * s, 0.7 * s), 0.06, angle=np.pi / 4),
                  Decal((0, 1), "rect", (0, 0), (0.15 * s, 0.7 * s), 0.06, angle=-np.pi / 4)]
    plate = Box((place[0], place[1], top), R, (0.01, s, s), 0.3, 0.0, decals, waves=None)
    pole = _upright((place[0], place[1], (top - s) / 2), (0.03, 0.03, max((top - s) / 2, 0.05)), 0.0, 0.35, rng, 0.0)
    return [plate, pole]


def _bollard(rng, place, pos) -> list[Box]:
    """A striped post or a low barrier."""
    if rng.random() < 0.5:
        h = rng.uniform(0.8, 1.2)
        decals = [Decal(None, "stripes", (0, 0), (0.2, h / 2), _retro(rng), rho2=0.08, period=0.2, duty=0.5,
                        pattern_angle=np.pi / 2)]
        return [_upright((place[0], place[1], h / 2), (0.1, 0.1, h / 2), rng.uniform(0, np.pi), 0.3, rng, 0.02, decals)]
    length, h = rng.uniform(0.8, 2.0), rng.uniform(0.8, 1.1)
    decals = [Decal(None, "stripes", (0, 0), (length, 0.12), 0.85, rho2=0.07, period=0.3, duty=0.5,
                    pattern_angle=np.pi / 4)]
    bar = _upright((place[0], place[1], h - 0.12), (0.03, length / 2, 0.12), _facing(place, pos) + rng.uniform(-0.5, 0.5),
                   0.5, rng, 0.02, decals)
    return [bar] + [
        _upright(np.array([place[0], place[1], (h - 0.24) / 2]) + bar.R @ np.array([0, side * (length / 2 - 0.05), 0]),
                 (0.03, 0.03, (h - 0.24) / 2), 0.0, 0.2, rng, 0.0)
        for side in (-1, 1)
    ]
