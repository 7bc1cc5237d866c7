"""The target: the object a lab mounts on its testbed and the dataset is of, loaded from a
target folder (``manifests.target``: ``DIR/target.toml`` beside its mesh).

Conventions (docs/architecture.md section 7): the body frame is the labels' frame; lengths
here are full scale, metres; the mock-up is the same shape scaled by ``mockup_scale``. The
mesh's lengths are converted with the folder's ``length_unit`` and moved into the body
frame with ``[frame] body_from_mesh``. A mesh file of several named parts (glTF nodes, PLY
and STL: one part named after the file) keeps them apart, so that renderers can give each
part its look.

Derived here, so that every stage agrees:
- ``centre_m``: the declared ``[frame] centre``, else the centre of the mesh's bounding box;
- ``radius_m``: the sphere about it that holds every vertex (plan keeps it in view);
- ``diameter_m``: the largest distance between two vertices (BOP's ``diameter``);
- keypoints, when the folder declares none: ``CHOSEN_KEYPOINTS`` corners of the mesh's
  convex hull by farthest-point sampling, starting from the one farthest from the centre
  (spread over the object, on its silhouette from many sides; ties by vertex order);
- views, when the folder declares none: the side of the plane through the centre normal
  to the body's z axis, ``plus_z`` / ``minus_z``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from manifests.sidecars.base import Pose
from manifests.target import (
    IDENTITY,
    LENGTH_UNITS,
    TARGET_FILE,
    Look,
    TargetError,
    TargetSpec,
    mesh_path,
    read_target_spec,
    target_digest,
)
from stages.common import geometry as g

#: keypoints chosen on a mesh that declares none (SPEED+ labels 11)
CHOSEN_KEYPOINTS = 11
#: a mock-up a robotic testbed can hold and light: its largest dimension (m)
MOCKUP_SIZE_M = (0.05, 3.0)
#: declared keypoints may stand this far beyond the bounding sphere (antenna tips, fillets)
KEYPOINT_MARGIN = 1.1
DEFAULT_VIEWS = ((0.0, 0.0, 1.0), ("plus_z", "minus_z"))


@dataclass(frozen=True)
class MeshPart:
    """Triangles of one part: vertices (V, 3) m, faces (F, 3) int, uv (V, 2) in [0, 1], and
    the mesh's own colour (linear RGB reflectance; None when it gives none)."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    colour: tuple[float, float, float] | None = None


@dataclass(frozen=True)
class Target:
    """A loaded target (full scale, metres, body frame); see the module docstring."""

    name: str
    parts: dict[str, MeshPart]
    keypoints_m: np.ndarray  # (K, 3)
    keypoints_chosen: bool  # True: chosen on the mesh, the folder declares none
    centre_m: np.ndarray  # (3,)
    radius_m: float
    diameter_m: float
    view_axis: np.ndarray  # (3,) unit
    view_names: tuple[str, str]
    mockup_scale: float
    mockup_mass_kg: float
    looks: dict[str, Look]
    digest: str  # sha256 of the folder's files: what the stages that use the target fingerprint
    #: the minus_x fixture's flange frame in T, full scale (the plus_x one is it turned half a
    #: turn about T's z through the body centre); declared in [mockup], else ``derived_fixture``
    fixture: Pose
    #: the calibration board's frame in T, full scale, when [mockup] declares it; else None:
    #: ``stages.common.layout.target_from_board`` lays the testbed's board on the mesh
    board: Pose | None
    #: BOP's symmetries in the body frame: (4, 4) transforms, translation in m; (axis (3,) unit,
    #: offset (3,) m) rotations of any angle
    symmetries_discrete: tuple[np.ndarray, ...] = ()
    symmetries_continuous: tuple[tuple[np.ndarray, np.ndarray], ...] = ()
    #: the motion-capture markers' centres (M, 3) in T, full scale, when [mockup] declares
    #: them; else None: ``stages.common.markers`` chooses them on the parts
    markers_m: np.ndarray | None = None

    @property
    def vertices_m(self) -> np.ndarray:
        """(V, 3) every part's vertices, full scale, in T (m): where the target can be, for
        the film windows of its renders and casts and for its symmetries."""
        return np.concatenate([part.vertices for part in self.parts.values()])

    def view_of(self, camera_in_target_m: np.ndarray, scale: float = 1.0) -> np.ndarray:
        """The view name (...) of camera positions (..., 3) in the body frame, metres at the
        given model scale: ``view_names[0]`` on the side of the plane through the centre
        that ``view_axis`` points to, else ``view_names[1]``."""
        side = (np.asarray(camera_in_target_m, float) - scale * self.centre_m) @ self.view_axis
        return np.where(side > 0, self.view_names[0], self.view_names[1])


#: the minus_x fixture's flange axes in T: its z (out of the flange) along T's +x
FIXTURE_Q = (0.0, math.sqrt(0.5), 0.0, math.sqrt(0.5))
#: the fixture's flange stands this far off the main body's -x face, on the mock-up (m)
FIXTURE_STAND_OFF_M = 0.12


def derived_fixture(target: Target) -> Pose:
    """Full scale: the minus_x fixture's flange ``FIXTURE_STAND_OFF_M`` (on the mock-up)
    beyond the main body box's -x face, level with the body centre, flange z along T's +x
    (``FIXTURE_Q``)."""
    low, _ = main_body_box(target)
    position = (low[0] - FIXTURE_STAND_OFF_M / target.mockup_scale, target.centre_m[1], target.centre_m[2])
    return Pose(FIXTURE_Q, tuple(float(v) for v in position))


def main_body_part(target: Target) -> MeshPart:
    """The target's main body: the part whose axis-aligned box is largest by volume (the
    first on a tie). Thin appendages (antennas, wings, booms) have flat boxes, so they never
    win over a body; a single-part mesh is its own. The fixtures hold it; declared
    motion-capture markers take their normals from its hull (``stages.common.markers``)."""
    parts = list(target.parts.values())
    volumes = [float(np.prod(part.vertices.max(axis=0) - part.vertices.min(axis=0))) for part in parts]
    return parts[int(np.argmax(volumes))]


def main_body_box(target: Target) -> tuple[np.ndarray, np.ndarray]:
    """Bounds (low, high) (3,) m, full scale, of the target's main body (``main_body_part``)."""
    vertices = main_body_part(target).vertices
    return vertices.min(axis=0), vertices.max(axis=0)


def feature_edges(target: Target, crease_deg: float = 20.0) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """A wireframe of the mesh: points (P, 3) m (body frame) and the edges (index pairs)
    where a part's surface creases by more than ``crease_deg`` or ends (an edge of one
    triangle). Vertices a part repeats at one place (a GLB's split normals) are one."""
    points: list[np.ndarray] = []
    edges: list[tuple[int, int]] = []
    for part in target.parts.values():
        unique, index = np.unique(np.round(part.vertices, 9), axis=0, return_inverse=True)
        faces = index.reshape(-1)[part.faces]
        corners = unique[faces]
        normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        length = np.linalg.norm(normals, axis=1)
        faces, normals = faces[length > 0], normals[length > 0] / length[length > 0, None]
        sides: dict[tuple[int, int], list[int]] = {}
        for face, (a, b, c) in enumerate(faces):
            for edge in ((a, b), (b, c), (c, a)):
                sides.setdefault((int(min(edge)), int(max(edge))), []).append(face)
        cos_crease = np.cos(np.radians(crease_deg))
        offset = sum(len(p) for p in points)
        for (a, b), adjacent in sorted(sides.items()):
            if len(adjacent) != 2 or normals[adjacent[0]] @ normals[adjacent[1]] < cos_crease:
                edges.append((offset + a, offset + b))
        points.append(unique)
    return np.concatenate(points), edges

def load_target(directory: Path) -> Target:
    """The target of a folder, every check done: ``TargetError`` names the file and key."""
    directory = Path(directory)
    spec = read_target_spec(directory)
    where = directory / TARGET_FILE
    body_from_mesh = g.transform_from_qt(spec.body_from_mesh.q, np.asarray(spec.body_from_mesh.t) * spec.metres)
    mesh = mesh_path(directory, spec)
    parts = {name: MeshPart(name, g.apply(body_from_mesh, part.vertices * spec.metres), part.faces, part.uv,
                            part.colour) for name, part in read_mesh(mesh).items()}
    vertices = np.concatenate([p.vertices for p in parts.values()])
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    centre = (low + high) / 2 if spec.centre is None else np.asarray(spec.centre) * spec.metres
    radius = float(np.max(np.linalg.norm(vertices - centre, axis=1)))
    hull = _hull(vertices, mesh)
    diameter = _diameter(hull)
    _check_size(where, spec, diameter)
    unknown = sorted(set(spec.looks) - set(parts))
    if unknown:
        raise TargetError(f"{where}: key looks.{unknown[0]}: the mesh has no part of that name "
                          f"(its parts: {', '.join(parts)})")
    if spec.keypoints is None:
        keypoints = farthest_points(hull, centre, CHOSEN_KEYPOINTS)
    else:
        keypoints = np.asarray(spec.keypoints, float) * spec.metres  # declared in the body frame already
        _check_keypoints(where, keypoints, centre, radius)
    axis, names = (spec.view_axis, spec.view_names) if spec.view_axis is not None else DEFAULT_VIEWS
    axis = np.asarray(axis, float)
    fixture, board = (None if pose is None else Pose(pose.q, tuple(v * spec.metres for v in pose.t))
                      for pose in (spec.fixture, spec.board))
    target = Target(spec.name, parts, keypoints, spec.keypoints is None, centre, radius, diameter,
                    axis / np.linalg.norm(axis), tuple(names), spec.mockup_scale, spec.mockup_mass_kg,
                    dict(spec.looks), target_digest(directory), IDENTITY, board)
    discrete = tuple(_metres(np.asarray(m, float).reshape(4, 4), spec.metres) for m in spec.symmetries_discrete)
    _check_symmetries(where, discrete, vertices, diameter)
    continuous = tuple((np.asarray(a, float) / np.linalg.norm(a), np.asarray(o, float) * spec.metres)
                       for a, o in spec.symmetries_continuous)
    markers = None if spec.markers is None else np.asarray(spec.markers, float) * spec.metres
    if markers is not None:
        _check_points(where, "mockup.markers", "marker", markers, centre, radius)
    return dataclasses.replace(target, fixture=derived_fixture(target) if fixture is None else fixture,
                               symmetries_discrete=discrete, symmetries_continuous=continuous, markers_m=markers)


def read_mesh(path: Path) -> dict[str, MeshPart]:
    """The mesh file's parts in its own units and frame; ``TargetError`` if it does not load
    or holds no triangles."""
    import trimesh  # loaded only where a mesh is read

    try:
        scene = trimesh.load(str(path), force="scene", process=False)
        placed = [(geometry, node, scene.graph.get(node)[0]) for geometry in scene.geometry
                  for node in scene.graph.geometry_nodes.get(geometry, [])]
    except Exception as error:  # noqa: BLE001 - trimesh raises anything from a broken file
        raise TargetError(f"{path}: not a mesh trimesh can read ({type(error).__name__}: {error})"[:400]) from None
    parts: dict[str, MeshPart] = {}
    for geometry, node, world_from_node in placed:  # in the file's order: renderers' shape order
        mesh = scene.geometry[geometry]
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            continue  # points, lines and empty nodes are not surfaces
        name = node if len(scene.graph.geometry_nodes[geometry]) == 1 else f"{geometry}_{node}"
        name = name[: -len(path.suffix)] if name.lower().endswith(path.suffix.lower()) else name  # STL, PLY
        vertices = g.apply(np.asarray(world_from_node, float), np.asarray(mesh.vertices, float))
        if not np.all(np.isfinite(vertices)):
            raise TargetError(f"{path}: part {name!r} has non-finite vertices")
        uv = getattr(mesh.visual, "uv", None)
        uv = np.zeros((len(vertices), 2)) if uv is None or len(uv) != len(vertices) else np.asarray(uv, float)
        while name in parts:
            name += "_"
        parts[name] = MeshPart(name, vertices, np.asarray(mesh.faces, np.int64), uv, mesh_colour(mesh))
    if not parts:
        raise TargetError(f"{path}: holds no triangles")
    area = sum(float(np.sum(np.linalg.norm(np.cross(p.vertices[p.faces[:, 1]] - p.vertices[p.faces[:, 0]],
                                                     p.vertices[p.faces[:, 2]] - p.vertices[p.faces[:, 0]]),
                                            axis=1))) / 2 for p in parts.values())
    if not area > 0:
        raise TargetError(f"{path}: every triangle is degenerate (zero area)")
    return parts


def farthest_points(points: np.ndarray, centre: np.ndarray, count: int) -> np.ndarray:
    """``count`` of ``points`` (N, 3) by farthest-point sampling, starting from the one
    farthest from ``centre``; fewer when there are fewer points."""
    chosen = [int(np.argmax(np.linalg.norm(points - centre, axis=1)))]
    distance = np.linalg.norm(points - points[chosen[0]], axis=1)
    while len(chosen) < min(count, len(points)):
        chosen.append(int(np.argmax(distance)))
        distance = np.minimum(distance, np.linalg.norm(points - points[chosen[-1]], axis=1))
    return points[chosen].copy()


def _hull(vertices: np.ndarray, path: Path) -> np.ndarray:
    """The convex hull's vertices (H, 3) in vertex order; a flat or linear mesh has none."""
    from scipy.spatial import ConvexHull, QhullError  # 0.4 s: every command resolves the stages that import this

    try:
        return vertices[np.sort(ConvexHull(vertices).vertices)]
    except QhullError:
        raise TargetError(f"{path}: the mesh is flat or degenerate (no volume); a target needs three "
                          "dimensions") from None


def _diameter(hull: np.ndarray) -> float:
    return float(max(np.max(np.linalg.norm(hull - p, axis=1)) for p in hull))


def _check_size(where: Path, spec: TargetSpec, diameter: float) -> None:
    """A unit mistake makes a mock-up of hundreds of metres or of millimetres."""
    mockup = diameter * spec.mockup_scale
    low, high = MOCKUP_SIZE_M
    if low <= mockup <= high:
        return
    other = "mm" if spec.length_unit == "m" else "m"
    as_other = diameter / spec.metres * LENGTH_UNITS[other] * spec.mockup_scale
    raise TargetError(f"{where}: key length_unit / mockup.scale: the mesh is {diameter:.4g} m across at full scale, "
                      f"{mockup:.4g} m as a mock-up at scale {spec.mockup_scale:g}, outside what a testbed holds "
                      f"({low:g}-{high:g} m); with length_unit = \"{other}\" the mock-up would be {as_other:.4g} m")


def _metres(transform: np.ndarray, metres: float) -> np.ndarray:
    out = transform.copy()
    out[:3, 3] *= metres
    return out


#: a declared discrete symmetry must put every vertex this close (share of the diameter) to one
SYMMETRY_TOLERANCE = 0.01


def _check_symmetries(where: Path, discrete: tuple[np.ndarray, ...], vertices: np.ndarray, diameter: float) -> None:
    """Each discrete symmetry maps the mesh onto itself: every vertex lands near a vertex."""
    from scipy.spatial import cKDTree

    tree = cKDTree(vertices)
    for index, transform in enumerate(discrete):
        distance, _ = tree.query(g.apply(transform, vertices))
        if distance.max() > SYMMETRY_TOLERANCE * diameter:
            raise TargetError(f"{where}: key symmetries.discrete.{index}: moves a vertex {distance.max():.4g} m from "
                              f"any vertex of the mesh (more than {SYMMETRY_TOLERANCE:.0%} of its {diameter:.4g} m): "
                              "not a symmetry of this mesh (another unit or frame?)")


def _check_keypoints(where: Path, keypoints: np.ndarray, centre: np.ndarray, radius: float) -> None:
    _check_points(where, "keypoints.points", "keypoint", keypoints, centre, radius)


def _check_points(where: Path, key: str, what: str, points: np.ndarray, centre: np.ndarray, radius: float) -> None:
    """Points (N, 3) m declared on the body lie near it: far outside, they are in another
    unit or frame."""
    distance = np.linalg.norm(points - centre, axis=1)
    far = np.flatnonzero(distance > KEYPOINT_MARGIN * radius)
    if far.size:
        i = int(far[0])
        raise TargetError(f"{where}: key {key}.{i}: {distance[i]:.4g} m from the body centre, outside the mesh "
                          f"(every vertex is within {radius:.4g} m): a {what} in another unit or frame?")


def mesh_colour(mesh: Any) -> tuple[float, float, float] | None:
    """A trimesh mesh's own colour as linear RGB reflectance, or None: a glTF material's
    base colour factor (linear already), an MTL's ``Kd`` or the mean vertex or face colour
    (both sRGB, linearised)."""
    visual = getattr(mesh, "visual", None)
    material = getattr(visual, "material", None)
    factor = getattr(material, "baseColorFactor", None)
    if factor is not None:
        rgb = np.asarray(factor, float).ravel()[:3]
        return tuple(float(v) for v in (rgb / 255.0 if rgb.max() > 1.0 else rgb))
    diffuse = getattr(material, "diffuse", None)
    if diffuse is not None:
        return _linear(np.asarray(diffuse, float).ravel()[:3] / 255.0)
    kind = getattr(visual, "kind", None)
    if kind in ("vertex", "face"):
        colours = visual.vertex_colors if kind == "vertex" else visual.face_colors
        return _linear(np.asarray(colours, float)[:, :3].mean(axis=0) / 255.0)
    return None


def _linear(srgb: np.ndarray) -> tuple[float, float, float]:
    linear = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
    return tuple(float(v) for v in np.clip(linear, 0.0, 1.0))
