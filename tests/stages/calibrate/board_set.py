"""A rendered eye-in-hand recording, as labs often take one: the flange visits a grid of
positions in one orientation, plus a few tilted views. The chessboard stands still in the
robot world; each image is the board's texture warped by the exact homography of its view
(pinhole camera, no distortion), so the truth (``cam_from_flange``) is known to the bit.

Written as a ``--format handeye`` folder (docs/user-guide.md, "Hand-eye folders"): ``images/*.png``,
``poses.txt`` (base_from_flange, row-major 4x4, metres) and ``dataset.toml``.
"""

from pathlib import Path

import cv2
import numpy as np

from stages.common import geometry as g

SIZE = (9, 6)  # inner corners
SQUARE_M = 0.025
WIDTH, HEIGHT = 960, 720
CAMERA = np.array([[900.0, 0, 479.5], [0, 900.0, 359.5], [0, 0, 1]])
#: the camera on the flange (the truth calibrate must find: its Z is cam_from_camee)
CAM_FROM_FLANGE = g.make_transform(g.rotvec_to_matrix([0.02, -0.03, 0.4]), [0.035, -0.02, 0.09])
BASE_FROM_BOARD = g.make_transform(g.rotvec_to_matrix([0.0, 0.0, 0.25]), [0.7, -0.1, 0.02])
PX_PER_SQUARE = 80


def board_texture() -> np.ndarray:
    """The printed board (H, W) uint8 with a one-square white margin; pixel (u, v) of the
    texture is the board point ((u + 0.5) / PX - 1 - 1, ...) squares from the first inner corner."""
    squares = (SIZE[0] + 1, SIZE[1] + 1)
    texture = np.full(((squares[1] + 2) * PX_PER_SQUARE, (squares[0] + 2) * PX_PER_SQUARE), 235, np.uint8)
    for i in range(squares[0]):
        for j in range(squares[1]):
            if (i + j) % 2 == 0:
                y, x = (j + 1) * PX_PER_SQUARE, (i + 1) * PX_PER_SQUARE
                texture[y:y + PX_PER_SQUARE, x:x + PX_PER_SQUARE] = 20
    return texture


def render(cam_from_board: np.ndarray, texture: np.ndarray) -> np.ndarray:
    """The board seen from ``cam_from_board`` (4, 4): a grey image (HEIGHT, WIDTH)."""
    # texture pixel centre (u, v) -> board metres: the first inner corner is 2 squares in
    metres_from_texture = np.array([[SQUARE_M / PX_PER_SQUARE, 0, -2 * SQUARE_M + 0.5 * SQUARE_M / PX_PER_SQUARE],
                                    [0, SQUARE_M / PX_PER_SQUARE, -2 * SQUARE_M + 0.5 * SQUARE_M / PX_PER_SQUARE],
                                    [0, 0, 1]])
    plane = cam_from_board[:3][:, [0, 1, 3]]  # board z = 0
    image_from_texture = CAMERA @ plane @ metres_from_texture
    image = cv2.warpPerspective(texture, image_from_texture, (WIDTH, HEIGHT), flags=cv2.INTER_AREA,
                                borderValue=128)
    return cv2.GaussianBlur(image, (0, 0), 0.7)


def views(n_grid: int = 11, tilted: int = 4, tilt_rad: float = 0.35,
          tilts: list[tuple[float, float]] | None = None) -> list[np.ndarray]:
    """``cam_from_board`` of each view: ``n_grid`` in one orientation over a grid of positions
    (the camera square to the board, 0.45-0.55 m away), then ``tilted`` views turned by
    ``tilt_rad`` about the board's x and y axes, both ways; or, with ``tilts``, one view per
    (about x, about y) turn (rad)."""
    centre = np.array([(SIZE[0] - 1) * SQUARE_M / 2, (SIZE[1] - 1) * SQUARE_M / 2, 0.0])
    facing = g.rotvec_to_matrix([0.0, 0.0, 0.1])
    out = []
    offsets = [(dx, dy) for dy in (-0.04, 0.0, 0.04) for dx in (-0.06, -0.02, 0.02, 0.06)][:n_grid]
    for k, (dx, dy) in enumerate(offsets):
        out.append(g.make_transform(facing, facing @ -centre + [dx, dy, 0.45 + 0.05 * (k % 3)]))
    turns = [(tilt_rad, 0.0), (-tilt_rad, 0.0), (0.0, tilt_rad), (0.0, -tilt_rad)][:tilted] if tilts is None else tilts
    for rotvec in ([x, y, 0.1] for x, y in turns):
        rotation = g.rotvec_to_matrix(rotvec)
        out.append(g.make_transform(rotation, rotation @ -centre + [0.0, 0.0, 0.5]))
    return out


def write(folder: Path, n_grid: int = 11, tilted: int = 4, robot_noise: tuple[float, float] = (0.0, 0.0),
          seed: int = 0, tilt_rad: float = 0.35, sag_rad: float = 0.0,
          tilts: list[tuple[float, float]] | None = None, scale: float = 1.0) -> dict[str, np.ndarray]:
    """The hand-eye folder; returns the truth (``cam_from_flange``, ``cam_from_board`` per view).
    ``robot_noise``: sigmas of the pose file's position (m) and angle (rad) per axis;
    ``sag_rad``: an error the robot does not report in the tilted views only (a bracket
    that sags when the flange tilts), which makes them the worst fitted; ``scale``: every
    length times this (the board's squares, the views' distances, the camera's offset on the
    flange; ``robot_noise`` as given): the same images of a larger board seen from farther."""
    rng = np.random.default_rng(seed)
    images = folder / "images"
    images.mkdir(parents=True)
    texture = board_texture()
    lines, truth = [], []
    cam_from_flange = g.make_transform(CAM_FROM_FLANGE[:3, :3], CAM_FROM_FLANGE[:3, 3] * scale)
    base_from_board = g.make_transform(BASE_FROM_BOARD[:3, :3], BASE_FROM_BOARD[:3, 3] * scale)
    for k, view in enumerate(views(n_grid, tilted, tilt_rad, tilts)):
        cv2.imwrite(str(images / f"view{k:02d}.png"), render(view, texture))
        cam_from_board = g.make_transform(view[:3, :3], view[:3, 3] * scale)
        base_from_flange = base_from_board @ g.invert(cam_from_board) @ cam_from_flange
        error = g.make_transform(g.rotvec_to_matrix(rng.normal(scale=robot_noise[1], size=3)),
                                 rng.normal(scale=robot_noise[0], size=3))
        base_from_flange = base_from_flange @ error
        if k >= n_grid:
            base_from_flange = base_from_flange @ g.make_transform(g.rotvec_to_matrix([sag_rad, 0.0, 0.0]), np.zeros(3))
        lines.append(" ".join(f"{v:.12g}" for v in base_from_flange.ravel()))
        truth.append(cam_from_board)
    (folder / "poses.txt").write_text("\n".join(lines) + "\n")
    square_m = SQUARE_M * scale
    k = ", ".join("[" + ", ".join(f"{v:g}" for v in row) + "]" for row in CAMERA)
    (folder / "dataset.toml").write_text(
        "format_version = 1\n[robot]\nfile = \"poses.txt\"\nlayout = \"rowmajor4x4\"\n"
        "transform = \"base_from_flange\"\nlength_unit = \"m\"\n[setup]\ncamera_on = \"flange\"\n"
        "[images]\nglob = \"images/*.png\"\n"
        f"[pattern]\nkind = \"chessboard\"\nsize = [{SIZE[0]}, {SIZE[1]}]\nsquare_m = {square_m:.12g}\n"
        f"[camera]\nwidth = {WIDTH}\nheight = {HEIGHT}\nK = [{k}]\ndist = [0, 0, 0, 0, 0]\n")
    return {"cam_from_flange": cam_from_flange, "cam_from_board": np.stack(truth)}
