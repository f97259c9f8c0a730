"""The cartoon world behind the synthetic scenes: boxes with painted decals, and ray casting.

Everything is an oriented box (pillars, cars, crates, sign plates, checkerboard targets, pipes);
the garage itself is one box seen from inside. Surfaces carry a reflectance: a base value with a
gentle low-frequency variation (concrete, paint) and flat decals painted on chosen faces
(parking lines, hazard stripes, signs, checkerboards, wheels, windows). Reflectance is 0..1 for
diffuse paint; values above 1 mark retro-reflective material (number plates, signs) that sends
far more light back towards the lidar and the camera beside it.

Ray casting is analytic (slab test) and vectorised over rays; a bounding-sphere test culls the
boxes a bundle of rays cannot reach. The scene layout itself lives in
:mod:`l2e_studio.synth.layout`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: For a hit on the face whose normal is local axis ``a``, the face coordinates (u, v) are these
#: two local axes (x, y, z = 0, 1, 2); the second is "up" on the side faces of upright boxes.
UV_AXES = {0: (1, 2), 1: (0, 2), 2: (0, 1)}


@dataclass
class Decal:
    """A flat pattern painted on a box face, in face coordinates (metres, box-centred).

    ``face`` is ``(axis, sign)`` of the face (``None``: every face, each in its own (u, v)).
    Shapes: ``rect``, ``disc`` (radius ``half[0]``), ``ring`` (outer radius ``half[0]``, inner
    ``half[1]`` painted ``rho2``), ``triangle`` (pointing to +v), ``checker`` (squares of side
    ``period``, ``rho``/``rho2``) and ``stripes`` (period ``period``, the ``duty`` share painted
    ``rho``, the rest ``rho2`` or left as is when ``rho2`` is None; stripes run at
    ``pattern_angle`` inside the rectangle).
    """

    face: tuple[int, int] | None
    shape: str
    center: tuple[float, float]
    half: tuple[float, float]
    rho: float
    angle: float = 0.0
    rho2: float | None = None
    period: float = 0.0
    duty: float = 0.5
    pattern_angle: float = 0.0

    def paint(self, u: np.ndarray, v: np.ndarray, rho: np.ndarray) -> None:
        """Write this decal's reflectance into ``rho`` where (u, v) falls inside it."""
        du = u - self.center[0]
        dv = v - self.center[1]
        reach = float(np.hypot(*self.half)) if self.shape not in ("disc", "ring") else self.half[0]
        near = (np.abs(du) <= reach) & (np.abs(dv) <= reach)
        if not near.any():
            return
        idx = np.flatnonzero(near)
        du, dv = du[idx], dv[idx]
        c, s = np.cos(self.angle), np.sin(self.angle)
        ru = c * du + s * dv
        rv = -s * du + c * dv
        hu, hv = self.half
        value = np.full(idx.size, self.rho)
        if self.shape == "rect":
            inside = (np.abs(ru) <= hu) & (np.abs(rv) <= hv)
        elif self.shape == "disc":
            inside = ru * ru + rv * rv <= hu * hu
        elif self.shape == "ring":
            r2 = ru * ru + rv * rv
            inside = r2 <= hu * hu
            if self.rho2 is not None:
                value[r2 <= hv * hv] = self.rho2
        elif self.shape == "triangle":
            inside = (rv >= -hv) & (np.abs(ru) <= hu * (hv - rv) / (2 * hv))
        elif self.shape == "checker":
            inside = (np.abs(ru) <= hu) & (np.abs(rv) <= hv)
            parity = (np.floor((ru + hu) / self.period) + np.floor((rv + hv) / self.period)) % 2
            value = np.where(parity == 0, self.rho, self.rho2 if self.rho2 is not None else 0.0)
        elif self.shape == "stripes":
            inside = (np.abs(ru) <= hu) & (np.abs(rv) <= hv)
            w = np.cos(self.pattern_angle) * ru + np.sin(self.pattern_angle) * rv
            on = (w / self.period) % 1.0 < self.duty
            if self.rho2 is None:
                inside &= on
            else:
                value = np.where(on, self.rho, self.rho2)
        else:  # pragma: no cover - layout code only builds the shapes above
            raise ValueError(f"unknown decal shape {self.shape!r}")
        rho[idx[inside]] = value[inside]


@dataclass
class Box:
    """An oriented box: ``X_world = center + R @ X_local``, ``|X_local| <= half`` per axis.

    ``inside`` marks the room, whose inner faces rays hit from within. ``grain`` is the amplitude
    of the low-frequency reflectance variation (a sum of a few random plane waves ``waves``).
    """

    center: np.ndarray
    R: np.ndarray
    half: np.ndarray
    base: float
    grain: float = 0.0
    decals: list[Decal] = field(default_factory=list)
    inside: bool = False
    waves: np.ndarray | None = None  # (k, 4): wave vector (rad/m) and phase

    def __post_init__(self) -> None:
        self.center = np.asarray(self.center, dtype=np.float64)
        self.R = np.asarray(self.R, dtype=np.float64)
        self.half = np.asarray(self.half, dtype=np.float64)
        self.radius = float(np.linalg.norm(self.half))

    def contains(self, point: np.ndarray, margin: float = 0.0) -> bool:
        local = (np.asarray(point, float) - self.center) @ self.R
        return bool(np.all(np.abs(local) <= self.half + margin))

    def reflectance(self, local: np.ndarray, axis: np.ndarray, sign: np.ndarray) -> np.ndarray:
        """Reflectance at box-local hit points on faces ``(axis, sign)``."""
        n = local.shape[0]
        rho = np.full(n, self.base)
        rows = np.arange(n)
        u_axis = np.array([UV_AXES[a][0] for a in range(3)])[axis]
        v_axis = np.array([UV_AXES[a][1] for a in range(3)])[axis]
        u = local[rows, u_axis]
        v = local[rows, v_axis]
        by_face: dict[tuple[int, int], np.ndarray] = {}
        for decal in self.decals:
            if decal.face is None:
                decal.paint(u, v, rho)
                continue
            idx = by_face.get(decal.face)
            if idx is None:
                idx = np.flatnonzero((axis == decal.face[0]) & (sign == decal.face[1]))
                by_face[decal.face] = idx
            if idx.size:
                sub = rho[idx]
                decal.paint(u[idx], v[idx], sub)
                rho[idx] = sub
        if self.grain and self.waves is not None:
            phase = local @ self.waves[:, :3].T + self.waves[:, 3]
            rho += self.grain * np.sin(phase).mean(axis=1)
        return np.clip(rho, 0.01, None)


def random_waves(rng: np.random.Generator, k: int = 4, wavelength: tuple[float, float] = (0.4, 4.0)) -> np.ndarray:
    """``k`` random plane waves (direction x wavenumber, phase) for reflectance grain."""
    dirs = rng.normal(size=(k, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    lam = rng.uniform(*wavelength, size=k)
    return np.column_stack([dirs * (2 * np.pi / lam)[:, None], rng.uniform(0, 2 * np.pi, k)])


@dataclass
class Hits:
    """First intersections of a bundle of rays: distance and box index (-1: none)."""

    t: np.ndarray
    index: np.ndarray


def cast(boxes: list[Box], origin: np.ndarray, dirs: np.ndarray, t_max: float | np.ndarray = np.inf) -> Hits:
    """Cast unit rays ``origin + t * dirs`` against ``boxes``; keep hits with ``1e-6 < t < t_max``.

    With ``t_max`` an array (one per ray) this is also a visibility test: ``index >= 0`` means
    something lies between the origin and the point at ``t_max``.
    """
    origin = np.asarray(origin, dtype=np.float64)
    n = dirs.shape[0]
    best_t = np.broadcast_to(np.asarray(t_max, dtype=np.float64), (n,)).copy()
    best_i = np.full(n, -1, dtype=np.int32)
    for i, box in enumerate(boxes):
        oc = box.center - origin
        if box.inside:
            idx = np.arange(n)
            d = dirs
        else:
            proj = dirs @ oc
            perp2 = float(oc @ oc) - proj * proj
            r = box.radius
            idx = np.flatnonzero((perp2 <= r * r) & (proj > -r) & (proj - r < best_t))
            if idx.size == 0:
                continue
            d = dirs[idx]
        d_local = d @ box.R
        d_local[d_local == 0.0] = 1e-18
        inv = 1.0 / d_local
        o_local = -oc @ box.R
        t1 = (-box.half - o_local) * inv
        t2 = (box.half - o_local) * inv
        if box.inside:
            t = np.maximum(t1, t2).min(axis=1)
            hit = t > 1e-6
        else:
            t_near = np.minimum(t1, t2).max(axis=1)
            t_far = np.maximum(t1, t2).min(axis=1)
            t = t_near
            hit = (t_near <= t_far) & (t_near > 1e-6)
        better = hit & (t < best_t[idx])
        rows = idx[better]
        best_t[rows] = t[better]
        best_i[rows] = i
    best_t[best_i < 0] = np.inf
    return Hits(best_t, best_i)


@dataclass
class Surface:
    """What the rays hit: world points, unit normals (facing the ray origin) and reflectance."""

    points: np.ndarray
    normals: np.ndarray
    rho: np.ndarray


def surface(boxes: list[Box], origin: np.ndarray, dirs: np.ndarray, hits: Hits) -> Surface:
    """World hit points, normals and reflectance for rays that hit something (``hits.index >= 0``)."""
    n = dirs.shape[0]
    points = origin + dirs * np.where(hits.index >= 0, hits.t, 0.0)[:, None]
    normals = np.zeros((n, 3))
    rho = np.zeros(n)
    for i in np.unique(hits.index[hits.index >= 0]):
        box = boxes[i]
        rows = np.flatnonzero(hits.index == i)
        local = (points[rows] - box.center) @ box.R
        axis = np.argmax(np.abs(local) / box.half, axis=1)
        sign = np.where(local[np.arange(rows.size), axis] >= 0, 1, -1)
        normal = box.R[:, axis].T * sign[:, None]
        flip = np.einsum("ij,ij->i", normal, dirs[rows]) > 0
        normal[flip] *= -1
        normals[rows] = normal
        rho[rows] = box.reflectance(local, axis, sign)
    return Surface(points, normals, rho)
