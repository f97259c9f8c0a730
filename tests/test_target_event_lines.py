"""A shaken board in its event map (detect.py stage 5, event_lines.py): lines two-coloured into a
checkerboard, found at the true corners; lines that are no board are not found."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from l2e_studio.camera import CameraModel
from l2e_studio.geometry import Extrinsic, project_points
from l2e_studio.target import Board, detect_board
from l2e_studio.target.event_lines import two_colour

CAM = CameraModel(np.array([[344.0, 0, 172], [0, 344, 130], [0, 0, 1]]), 346, 260, np.zeros(5))
BOARD = Board("checkerboard", (10, 7), 0.068, (0.8, 0.6))


def _true_corners(pose: Extrinsic, board: Board) -> np.ndarray:
    uv, _ = project_points(pose.transform(board.corners()), CAM)
    return uv


def _corner_error(found: np.ndarray, truth: np.ndarray) -> float:
    """RMS px, either corner order (a symmetric grid may be numbered from either end)."""
    return min(float(np.sqrt(np.mean(np.sum((c - truth) ** 2, axis=1)))) for c in (found, found[::-1]))


def _line_map(pose: Extrinsic, squares: tuple[int, int], rng, width: int = 3) -> np.ndarray:
    """An event map of a board's edges at ``pose``: the sides of its black squares and its
    outline drawn ``width`` px wide with speckled counts, over noise events."""
    cols, rows = squares
    s = BOARD.square_m
    img = np.zeros((CAM.height, CAM.width), np.float32)
    black = lambda i, j: 0 <= i < cols and 0 <= j < rows and (i + j) % 2 == 0
    segments = []  # every side of a black square: the edges between black and white (or the margin)
    for i in range(cols):
        for j in range(rows):
            if black(i, j):
                x, y = (i - cols / 2) * s, (j - rows / 2) * s
                segments += [(x, y, x + s, y), (x + s, y, x + s, y + s), (x + s, y + s, x, y + s), (x, y + s, x, y)]
    w, h = BOARD.size_m[0] / 2, BOARD.size_m[1] / 2
    segments += [(-w, -h, w, -h), (w, -h, w, h), (w, h, -w, h), (-w, h, -w, -h)]
    for x0, y0, x1, y1 in segments:
        t = np.linspace(0, 1, 40)
        pts = np.column_stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0), np.zeros(40)])
        uv, _ = project_points(pose.transform(pts), CAM)
        cv2.polylines(img, [np.round(uv * 16).astype(np.int32)], False, 1.0, width, cv2.LINE_AA, shift=4)
    img = img * rng.uniform(60, 140, img.shape) + rng.poisson(1.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def test_shaken_board_event_maps_are_found_at_the_true_corners():
    """Synthetic shaken boards (``events-moving``: 1.5 cm / 1.5 deg about the true pose, events
    at the edges, the aperture problem included): stages 1-4 find none of them; stage 5 finds
    the boards whose both edge families fired, at the true corners (the edges' mean position
    over the shake) to a fraction of a pixel, and the reprojection error says as much."""
    from l2e_studio.synth import TargetConfig, make_target_rig, make_target_scene
    from l2e_studio.synth.board import pixel_rays

    config = TargetConfig(n_scenes=10, modality="events-moving", seed=1)
    camera, truth, _ = make_target_rig(config)
    rays = pixel_rays(camera)
    board = Board("checkerboard", config.board.squares, config.board.square_m, config.board.size_m)
    errors = []
    for i in range(5):  # the near half of the sequence (squares 9-13 px)
        image, *_, scene = make_target_scene(config, i, camera, truth, rays)
        det = detect_board(image, board, camera, f"f{i}")
        if not det.found:
            assert "event lines two-coloured" in det.reason
            continue
        assert "event lines two-coloured" in det.method, det.method
        truth_uv, _ = project_points(scene.pose_cam.transform(config.board.inner_corners()), camera)
        errors.append(_corner_error(det.corners, truth_uv))
        assert det.reprojection_px < 1.0
    assert len(errors) >= 2, errors
    assert np.median(errors) < 0.4, errors


def test_a_grid_of_event_lines_is_found_with_its_inner_corners():
    """A clean map of a board's edge lines, 3 px wide (the centre of each line is the edge):
    found, the inner corners within half a pixel (RMS) of the truth."""
    pose = Extrinsic.from_rpy([15.0, -20.0, 8.0], [0.05, -0.02, 1.6])
    det = detect_board(_line_map(pose, BOARD.squares, np.random.default_rng(0)), BOARD, CAM, "grid")
    assert det.found, det.reason
    assert "event lines two-coloured" in det.method
    assert _corner_error(det.corners, _true_corners(pose, BOARD)) < 0.5


def test_lines_that_are_not_this_board_are_not_found():
    """Random lines over noise, a grid with one line family missing (the shake ran along it),
    and a grid of 9 x 7 squares for a 10 x 7 board: each is "not found" with the reason."""
    rng = np.random.default_rng(1)
    random = rng.poisson(1.0, (CAM.height, CAM.width)).astype(np.float32)
    for _ in range(40):
        p, q = rng.uniform([0, 0], [CAM.width, CAM.height], (2, 2))
        cv2.line(random, tuple(int(v) for v in p), tuple(int(v) for v in q), float(rng.uniform(60, 200)), 3)
    pose = Extrinsic.from_rpy([10.0, 12.0, -5.0], [0.0, 0.0, 1.7])
    stripes = _line_map(pose, BOARD.squares, rng).astype(np.float32)
    mask = np.zeros_like(stripes)
    for j in range(BOARD.squares[1] + 1):  # keep only the lines along the rows, the outline's two
        y = (j - BOARD.squares[1] / 2) * BOARD.square_m
        uv, _ = project_points(pose.transform(np.array([[-0.4, y, 0], [0.4, y, 0]])), CAM)
        cv2.line(mask, tuple(int(v) for v in uv[0]), tuple(int(v) for v in uv[1]), 1.0, 5)
    stripes = stripes * mask + rng.poisson(1.0, stripes.shape)
    wrong_count = _line_map(pose, (9, 7), rng)
    for name, image in (("random", random), ("stripes", stripes), ("9x7", wrong_count)):
        det = detect_board(np.clip(image, 0, 255).astype(np.uint8), BOARD, CAM, name)
        assert not det.found, name
        assert "event lines two-coloured" in det.reason, (name, det.reason)


@pytest.mark.parametrize("odd", [False, True])
def test_two_colouring_drops_the_cells_of_an_odd_cycle(odd):
    """A 4 x 4 grid of cells two-colours checkerwise; a false link across a diagonal (two cells
    of one colour, as a missing line leaves them) makes an odd cycle: its cells are dropped,
    the rest keep one consistent colouring."""
    graph: dict[int, set[int]] = {}
    cell = lambda r, c: 1 + 4 * r + c
    for r in range(4):
        for c in range(4):
            for rr, cc in ((r + 1, c), (r, c + 1)):
                if rr < 4 and cc < 4:
                    graph.setdefault(cell(r, c), set()).add(cell(rr, cc))
                    graph.setdefault(cell(rr, cc), set()).add(cell(r, c))
    if odd:
        graph[cell(1, 1)].add(cell(2, 2))
        graph[cell(2, 2)].add(cell(1, 1))
    colour = two_colour(graph, np.ones(17))
    for a, bs in graph.items():
        for b in bs:
            if a in colour and b in colour:
                assert colour[a] != colour[b]
    assert len(colour) == (15 if odd else 16)
    if not odd:
        assert len({colour[cell(0, 0)], colour[cell(0, 1)]}) == 2
