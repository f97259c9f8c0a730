"""Plane intersections as lidar edges (issue 16, stop 33): depth-continuous edges for sparse scans.

A 16-beam scan places a depth discontinuity only to within its ring spacing vertically (2 deg
on a VLP-16), so a horizontal occluding edge can sit anywhere in a 2 deg band. Where two planes
meet (a wall's corner, a facade on the ground, a kerb) the line of their intersection follows
from many rings at once and is placed far better than any ring (after Yuan et al., RA-L 2021,
"Pixel-level extrinsic self calibration of high resolution LiDAR and camera in targetless
environments", which matches such lines against image edges). This study adds them to the
lidar side of the edge score and measures, at each dev rig's reference, the share of 24 random
rotations 0.5 / 1 / 2 / 5 deg off that score at least as high (0 everywhere: the score peaks
at the reference), as ``study_edge_kinds.py`` does:

    python benchmarks/study_plane_lines.py --rigs hitsz_vlp16,lcecalib_rles01_frame,1+2,manual

* ``engine``: the lidar edges as they are;
* ``+lines``: and points along plane intersections (weight ``--line-weight``);
* ``lines``: plane intersections alone.

Planes: the scan cut into cubes of ``--voxel`` m; a cube whose points spread over two
directions (more than one ring) and lie within a few cm of their mean plane is a planar patch;
neighbouring patches of one plane are merged. Two planes whose normals differ by 30-150 deg give
the stretch of their intersection line that both planes' points come near, sampled every 5 cm.
The table also counts the line points in the image at the reference (all scenes).
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from l2e_studio.geometry import in_image, project_points
from l2e_studio.scenes import Scene
from realdata_rigs import load_rigs
from study_edge_kinds import ENGINE, random_directions, shares

THICK_M = 0.04  # a patch's points within this RMS of their plane
MIN_POINTS = 12
STEP_M = 0.05  # line points this far apart
MERGE_M = 0.08  # neighbouring patches of one plane: each centroid this near the other's plane
MIN_PLANE = 40  # points of a plane's own patches
INLIER_M = 0.06  # a plane's points: within this of it, in its cubes and their neighbours
NEAR_M = 0.25  # both planes' points within this of the line, at the same place along it


def plane_lines(points: np.ndarray, voxel: float) -> np.ndarray:
    """(M, 3) points along the intersections of the planes of ``points``.

    Planar patches (cubes of ``voxel`` m whose points spread over two directions within
    ``THICK_M`` of their plane) are merged with their neighbours of the same plane; each plane
    takes every point within ``INLIER_M`` of it in its cubes and theirs (the cube at a corner
    holds two planes and is no patch itself). Two planes whose normals differ by 30-150 deg give
    the stretch of their intersection line that both planes' points come within ``NEAR_M`` of."""
    P = np.asarray(points, np.float64)
    P = P[np.all(np.isfinite(P), axis=1)]
    key = np.floor(P / voxel).astype(np.int64)
    cells, inv, count = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    n = np.maximum(count, 1)[:, None]
    mean = np.stack([np.bincount(inv, P[:, k], len(cells)) for k in range(3)], 1) / n
    D = P - mean[inv]
    cov = np.stack([np.stack([np.bincount(inv, D[:, i] * D[:, j], len(cells)) for j in range(3)], 1)
                    for i in range(3)], 1) / n[:, :, None]
    lam, vec = np.linalg.eigh(cov)
    s = np.sqrt(np.maximum(lam, 0))
    planar = (count >= MIN_POINTS) & (s[:, 0] < THICK_M) & (s[:, 1] > voxel / 8)
    normal = vec[:, :, 0]
    lookup = {tuple(c): i for i, c in enumerate(cells)}
    nbrs = [(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1) if (a, b, c) != (0, 0, 0)]

    def around(i):
        for o in nbrs:
            j = lookup.get((cells[i][0] + o[0], cells[i][1] + o[1], cells[i][2] + o[2]))
            if j is not None:
                yield j

    parent = {i: i for i in np.flatnonzero(planar)}

    def root(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i in parent:
        for j in around(i):
            if j in parent and abs(normal[i] @ normal[j]) > np.cos(np.radians(10)) \
                    and abs(normal[i] @ (mean[j] - mean[i])) < MERGE_M and abs(normal[j] @ (mean[i] - mean[j])) < MERGE_M:
                parent[root(i)] = root(j)
    groups: dict[int, list[int]] = {}
    for i in parent:
        groups.setdefault(root(i), []).append(i)
    order = np.argsort(inv, kind="stable")
    starts = np.r_[0, np.cumsum(count)]
    planes = []
    for members in groups.values():
        own = P[np.concatenate([order[starts[c]:starts[c + 1]] for c in members])]
        if len(own) < MIN_PLANE:
            continue
        c0 = own.mean(0)
        nrm = np.linalg.eigh(np.cov((own - c0).T))[1][:, 0]
        cand = set(members)
        for c in members:
            cand.update(around(c))
        pts = P[np.concatenate([order[starts[c]:starts[c + 1]] for c in cand])]
        pts = pts[np.abs((pts - c0) @ nrm) < INLIER_M]
        planes.append((c0, nrm, pts))
    out = []
    for a in range(len(planes)):
        for b in range(a + 1, len(planes)):
            (c1, n1, p1), (c2, n2, p2) = planes[a], planes[b]
            if abs(n1 @ n2) > np.cos(np.radians(30)):
                continue
            d = np.cross(n1, n2)
            d /= np.linalg.norm(d)
            x0 = np.linalg.solve(np.stack([n1, n2, d]), [n1 @ c1, n2 @ c2, d @ (c1 + c2) / 2])
            spans = []
            for q in (p1 - x0, p2 - x0):
                t = q @ d
                near = np.linalg.norm(q - t[:, None] * d, axis=1) < NEAR_M
                spans.append(np.round(t[near] / STEP_M).astype(np.int64))
            both = np.intersect1d(spans[0], spans[1])
            if len(both) >= 3:
                out.append(x0 + (both * STEP_M)[:, None] * d)
    return np.concatenate(out) if out else np.zeros((0, 3))


def with_lines(scene: Scene, voxel: float, only: bool) -> Scene:
    """``scene`` with its plane-intersection points appended (intensity -1 marks them)."""
    lines = plane_lines(scene.points, voxel).astype(np.float32)
    if only:
        return replace(scene, points=lines, intensity=np.full(len(lines), -1.0, np.float32))
    return replace(scene, points=np.concatenate([np.asarray(scene.points, np.float32), lines]),
                   intensity=np.concatenate([np.asarray(scene.intensity, np.float32),
                                             np.full(len(lines), -1.0, np.float32)]))


def weights(line_weight: float):
    def w(points, intensity):
        intensity = np.asarray(intensity)
        mark = intensity < 0
        out = np.full(len(points), line_weight, np.float32)
        if (~mark).any():
            out[~mark] = ENGINE(np.asarray(points)[~mark], intensity[~mark])
        return out
    return w


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rigs", default="manual,1+2,kitti_odometry_00,hitsz_vlp16,lcecalib_rlfs01,lcecalib_rles01_frame")
    p.add_argument("--voxel", type=float, default=1.0)
    p.add_argument("--line-weight", type=float, default=1.0)
    args = p.parse_args()
    directions = random_directions()
    print("| rig | line points in view | engine | +lines | lines |\n|---|---|---|---|---|")
    for rig in load_rigs(args.rigs.split(",")):
        lines = [plane_lines(sc.points, args.voxel) for sc in rig.scenes]
        uv, front = project_points(rig.reference.transform(np.concatenate(lines)), rig.camera)
        cells = [f"{int((front & in_image(uv, rig.camera)).sum())} of {sum(map(len, lines))}"]
        for variant in ("engine", "+lines", "lines"):
            scenes = rig.scenes if variant == "engine" else tuple(
                with_lines(sc, args.voxel, variant == "lines") for sc in rig.scenes)
            s = shares(rig, weights(args.line_weight), directions, scenes)
            cells.append(" / ".join(f"{x:.2f}" for x in s))
        print(f"| {rig.name} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
