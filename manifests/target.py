"""A target folder: the object a lab mounts, as ``DIR/target.toml`` beside its mesh
(docs/architecture.md section 7). Format version 1; every error names the file and the
key (or the line and column of a TOML syntax error).

    DIR/target.toml
    format_version = 1
    name = "cubesat6u"            # [a-z0-9_-]+
    mesh = "cubesat6u.glb"        # relative to DIR: glTF/GLB, OBJ (+MTL), PLY or STL
    length_unit = "m"             # or "mm": the mesh and every length in this file
    [frame]                       # optional: the body frame the labels use, from the mesh's
    body_from_mesh_q = [1, 0, 0, 0]   # (w, x, y, z)
    body_from_mesh_t = [0, 0, 0]      # length_unit
    centre = [0, 0, 0.16]         # optional, body frame: the body centre (default: the
                                  # centre of the mesh's bounding box)
    [keypoints]                   # optional; absent: chosen on the mesh (stages.common.target)
    points = [[x, y, z], ...]     # body frame, length_unit; at least 4
    [views]                       # optional: the camera's side of the plane through the
    axis = [0, 0, 1]              # body centre normal to axis names the view
    names = ["top", "bottom"]     # (positive side, negative side)
    [mockup]
    scale = 0.5                   # mock-up size / real size
    mass_kg = 4.0
    fixture_q = [w, x, y, z]      # optional: where the minus_x fixture's flange frame is in
    fixture_t = [x, y, z]         # the body frame (length_unit, full scale; flange z along +x);
                                  # absent: 12 cm (on the mock-up) off the main body's -x face
    board_q = [w, x, y, z]        # optional: where the calibration board lies (OpenCV ChArUco
    board_t = [x, y, z]           # frame: origin at a corner, z into the board); absent: on the
                                  # mesh's top (+z, the fixtures hold -x and +x), centred, on a
                                  # 3 mm plate
    markers = [[x, y, z], ...]    # optional: the motion-capture markers' centres (body frame,
                                  # length_unit, full scale; at least 4); absent: chosen on the
                                  # main body's surface (stages.common.markers)
    [symmetries]                  # optional (BOP's models_info): poses that map the mesh onto itself
    discrete = [[16 numbers], ...]    # 4 x 4 row-major body-frame transforms (translation in length_unit)
    continuous = [{ axis = [0, 0, 1], offset = [0, 0, 0] }]   # rotation about an axis through offset
    [looks]                       # optional, per mesh part: a preset of LOOK_PRESETS, or
    sides = "gold_mli"            # {synthetic = ..., mockup = ...} for two different ones
    antennas = { synthetic = "aluminium", mockup = "white_paint" }

Each preset has an ideal version for the rendered twin and a mock-up version for the
testbed (crinkled foil, printed cells, brushed metal): their difference is the domain gap.
A part without a look renders with the mesh's own colours on the twin and white paint on
the mock-up.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import Any

import numpy as np
import tomli_w

from manifests.files import write_bytes_atomic
from manifests.schema import NAME_PATTERN
from manifests.sidecars.base import Fields, Pose, SidecarError, read_toml

TARGET_FILE = "target.toml"
TARGET_FORMAT_VERSION = 1
#: metres per unit
LENGTH_UNITS = {"m": 1.0, "mm": 1e-3}
MESH_SUFFIXES = (".glb", ".gltf", ".obj", ".ply", ".stl")
#: the looks a part can take (stages.common.target documents each)
LOOK_PRESETS = ("gold_mli", "solar_cells", "aluminium", "white_paint", "black_paint", "rock")
MIN_KEYPOINTS = 4
#: a rigid body Vicon tracks needs 3 markers in sight; 4 keep it when one is hidden
MIN_MARKERS = 4
IDENTITY = Pose((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0))


class TargetError(SidecarError):
    """A target folder that cannot be used as it is."""


@dataclass(frozen=True)
class Look:
    """A part's look (``LOOK_PRESETS``): the preset whose ideal version the synthetic twin
    takes, and the one whose mock-up version the testbed's model takes."""

    synthetic: str
    mockup: str


@dataclass(frozen=True)
class TargetSpec:
    """``target.toml`` as written: lengths in ``length_unit``, not yet applied to the mesh."""

    name: str
    mesh: str
    length_unit: str
    mockup_scale: float
    mockup_mass_kg: float
    body_from_mesh: Pose = IDENTITY
    centre: tuple[float, float, float] | None = None
    keypoints: tuple[tuple[float, float, float], ...] | None = None
    view_axis: tuple[float, float, float] | None = None
    view_names: tuple[str, str] | None = None
    looks: dict[str, Look] = field(default_factory=dict)
    fixture: Pose | None = None  # the minus_x fixture's flange frame in the body frame
    board: Pose | None = None  # the calibration board's frame in the body frame
    #: 4 x 4 row-major transforms (16,) in the body frame, translation in length_unit
    symmetries_discrete: tuple[tuple[float, ...], ...] = ()
    #: (axis (3,), offset (3,) in length_unit) of each continuous symmetry
    symmetries_continuous: tuple[tuple[tuple[float, float, float], tuple[float, float, float]], ...] = ()
    #: the motion-capture markers' centres (body frame, length_unit, full scale); None: chosen
    markers: tuple[tuple[float, float, float], ...] | None = None

    @property
    def metres(self) -> float:
        return LENGTH_UNITS[self.length_unit]

    def to_toml(self) -> dict[str, Any]:
        out: dict[str, Any] = {"format_version": TARGET_FORMAT_VERSION, "name": self.name, "mesh": self.mesh,
                               "length_unit": self.length_unit}
        frame: dict[str, Any] = {}
        if self.body_from_mesh != IDENTITY:
            frame = {"body_from_mesh_q": list(self.body_from_mesh.q), "body_from_mesh_t": list(self.body_from_mesh.t)}
        if self.centre is not None:
            frame["centre"] = list(self.centre)
        if frame:
            out["frame"] = frame
        if self.keypoints is not None:
            out["keypoints"] = {"points": [list(p) for p in self.keypoints]}
        if self.view_axis is not None and self.view_names is not None:
            out["views"] = {"axis": list(self.view_axis), "names": list(self.view_names)}
        out["mockup"] = {"scale": self.mockup_scale, "mass_kg": self.mockup_mass_kg}
        for name, pose in (("fixture", self.fixture), ("board", self.board)):
            if pose is not None:
                out["mockup"].update({f"{name}_q": list(pose.q), f"{name}_t": list(pose.t)})
        if self.markers is not None:
            out["mockup"]["markers"] = [list(p) for p in self.markers]
        if self.symmetries_discrete or self.symmetries_continuous:
            out["symmetries"] = {
                **({"discrete": [list(m) for m in self.symmetries_discrete]} if self.symmetries_discrete else {}),
                **({"continuous": [{"axis": list(a), "offset": list(o)} for a, o in self.symmetries_continuous]}
                   if self.symmetries_continuous else {})}
        if self.looks:
            out["looks"] = {part: look.synthetic if look.synthetic == look.mockup else
                            {"synthetic": look.synthetic, "mockup": look.mockup}
                            for part, look in sorted(self.looks.items())}
        return out


def mesh_path(directory: Path, spec: TargetSpec) -> Path:
    """The mesh file, checked to stay inside ``directory`` (no absolute path, no ``..``, no
    link out of it)."""
    where = directory / TARGET_FILE
    relative = PurePosixPath(spec.mesh)
    if relative.is_absolute() or ".." in relative.parts or "\\" in spec.mesh or not relative.parts:
        raise TargetError(f"{where}: key mesh: expected a path inside {directory}, got {spec.mesh!r}")
    path = directory / relative
    if not path.resolve().is_relative_to(directory.resolve()):
        raise TargetError(f"{where}: key mesh: {spec.mesh!r} leads out of {directory}")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise TargetError(f"{where}: key mesh: expected a {', '.join(MESH_SUFFIXES)} file, got {spec.mesh!r}")
    if not path.is_file():
        raise TargetError(f"{where}: key mesh: {path} does not exist")
    for reference in referenced_files(path):
        inside(directory, path, reference)
    return path


def referenced_files(mesh: Path) -> list[str]:
    """The files a mesh file names (a glTF's buffers and images, an OBJ's material
    libraries and their texture maps), as written in it; ``data:`` URIs are inline."""
    try:
        if mesh.suffix.lower() == ".gltf":
            document = json.loads(mesh.read_text(encoding="utf-8"))
            return [entry["uri"] for key in ("buffers", "images") for entry in document.get(key, [])
                    if isinstance(entry, dict) and isinstance(entry.get("uri"), str)
                    and not entry["uri"].startswith("data:")]
        if mesh.suffix.lower() == ".obj":
            libraries = [line.split(maxsplit=1)[1].strip() for line in mesh.read_text(errors="replace").splitlines()
                         if line.startswith("mtllib ") and len(line.split(maxsplit=1)) == 2]
            maps = []
            for library in libraries:
                material = mesh.parent / library
                if material.is_file() and material.resolve().is_relative_to(mesh.parent.resolve()):
                    maps += [line.split()[-1] for line in material.read_text(errors="replace").splitlines()
                             if line.strip().lower().startswith("map_") and len(line.split()) > 1]
            return libraries + maps
    except (OSError, ValueError) as error:  # unreadable, or a glTF that is not JSON: trimesh says more
        raise TargetError(f"{mesh}: cannot read the files it names ({error})"[:400]) from None
    return []


def inside(directory: Path, mesh: Path, reference: str) -> None:
    """A file the mesh names must stay inside the target folder."""
    relative = PurePosixPath(reference.replace("\\", "/"))
    if (relative.is_absolute() or ".." in relative.parts
            or not (mesh.parent / relative).resolve().is_relative_to(directory.resolve())):
        raise TargetError(f"{mesh}: names {reference!r}, which is outside the target folder {directory}")


def target_files(directory: Path) -> list[str]:
    """The files a target consists of, relative to ``directory`` (POSIX, sorted):
    ``target.toml``, the mesh and the files the mesh names. What a workspace copies and
    what its digest covers; other files in the folder (a lab's CAD sources) are not part of it."""
    directory = Path(directory)
    spec = read_target_spec(directory)
    mesh = mesh_path(directory, spec)
    names = {TARGET_FILE, mesh.relative_to(directory).as_posix()}
    for reference in referenced_files(mesh):
        path = (mesh.parent / reference.replace("\\", "/")).resolve()
        if path.is_file():  # a missing texture is trimesh's to report
            names.add(path.relative_to(directory.resolve()).as_posix())
    return sorted(names)


def target_digest(directory: Path) -> str:
    """sha256 over the target's files (``target_files``: relative path and bytes, in order)."""
    digest = hashlib.sha256()
    for name in target_files(directory):
        digest.update(name.encode() + b"\0")
        try:
            digest.update((Path(directory) / name).read_bytes())
        except OSError as error:
            raise TargetError(f"{Path(directory) / name}: cannot be read ({error.strerror or error})") from None
    return digest.hexdigest()


def read_target_spec(directory: Path) -> TargetSpec:
    """``DIR/target.toml``, validated (not the mesh: ``stages.common.target.load_target``)."""
    path = Path(directory) / TARGET_FILE
    data = read_toml(path, TargetError, "a target folder holds target.toml beside its mesh")
    try:
        return _parse(Fields(data, str(path), ""), Path(directory))
    except TargetError:
        raise
    except SidecarError as error:  # the walker's: the same message, as a target's error
        raise TargetError(str(error)) from None


def _parse(f: Fields, directory: Path) -> TargetSpec:
    data = f.data
    f.only("format_version", "name", "mesh", "length_unit", "frame", "keypoints", "views", "mockup", "symmetries",
           "looks")
    if data.get("format_version") != TARGET_FORMAT_VERSION:
        raise f.fail("format_version", f"{TARGET_FORMAT_VERSION} (this program reads version {TARGET_FORMAT_VERSION})")
    name = f.text("name")
    if not NAME_PATTERN.fullmatch(name):
        raise f.fail("name", "a name of a-z, 0-9, _ and -")
    scale, mass, fixture, board = _mockup(f)
    spec = TargetSpec(name, f.text("mesh"), f.text("length_unit", tuple(LENGTH_UNITS)), scale, mass,
                      *_frame(f), _keypoints(f), *_views(f), _looks(f), fixture, board, *_symmetries(f),
                      _markers(f.child("mockup")))
    mesh_path(directory, spec)
    return spec


def write_target_spec(directory: Path, spec: TargetSpec) -> None:
    write_bytes_atomic(Path(directory) / TARGET_FILE, to_text(spec.to_toml()).encode())


def to_text(document: dict[str, Any]) -> str:
    """TOML as a person writes it: a table per section, a keypoint per line (``tomllib``
    reads it back to ``document``)."""
    def value(v: Any) -> str:
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {value(x)}" for k, x in v.items()) + " }"
        if isinstance(v, list):
            if v and isinstance(v[0], list):
                return "[\n" + "".join(f"    {value(x)},\n" for x in v) + "]"
            return "[" + ", ".join(value(x) for x in v) + "]"
        return tomli_w.dumps({"v": v})[4:].strip()

    lines = [f"{k} = {value(v)}" for k, v in document.items() if not isinstance(v, dict)]
    for section, table in ((k, v) for k, v in document.items() if isinstance(v, dict)):
        lines += ["", f"[{section}]", *(f"{k} = {value(v)}" for k, v in table.items())]
    return "\n".join(lines) + "\n"


def _mockup(f: Fields) -> tuple[float, float, Pose | None, Pose | None]:
    mockup = f.child("mockup")
    mockup.only("scale", "mass_kg", "fixture_q", "fixture_t", "board_q", "board_t", "markers")
    poses = []
    for name in ("fixture", "board"):
        given = [mockup.optional(f"{name}_q"), mockup.optional(f"{name}_t")]
        if not any(given):
            poses.append(None)
            continue
        if not all(given):
            raise mockup.fail(f"{name}_{'t' if given[0] else 'q'}", f"given with {name}_{'q' if given[0] else 't'}")
        q = mockup.vector(f"{name}_q", 4)
        if abs(math.sqrt(sum(v * v for v in q)) - 1.0) > 1e-6:
            raise mockup.fail(f"{name}_q", "a unit quaternion (w, x, y, z)")
        poses.append(Pose(tuple(map(float, q)), tuple(map(float, mockup.vector(f"{name}_t", 3)))))
    return mockup.number("scale", positive=True), mockup.number("mass_kg", positive=True), poses[0], poses[1]


def _frame(f: Fields) -> tuple[Pose, tuple[float, float, float] | None]:
    if not f.optional("frame"):
        return IDENTITY, None
    frame = f.child("frame")
    frame.only("body_from_mesh_q", "body_from_mesh_t", "centre")
    q = frame.vector("body_from_mesh_q", 4) if frame.optional("body_from_mesh_q") else IDENTITY.q
    if abs(math.sqrt(sum(v * v for v in q)) - 1.0) > 1e-6:
        raise frame.fail("body_from_mesh_q", "a unit quaternion (w, x, y, z)")
    t = frame.vector("body_from_mesh_t", 3) if frame.optional("body_from_mesh_t") else IDENTITY.t
    centre = frame.vector("centre", 3) if frame.optional("centre") else None
    return Pose(tuple(map(float, q)), tuple(map(float, t))), centre


def _markers(mockup: Fields) -> tuple[tuple[float, float, float], ...] | None:
    if not mockup.optional("markers"):
        return None
    markers = mockup.raw("markers")
    if not isinstance(markers, list) or len(markers) < MIN_MARKERS:
        raise mockup.fail("markers", f"a list of at least {MIN_MARKERS} [x, y, z] marker centres")
    inner = Fields({str(i): p for i, p in enumerate(markers)}, mockup.where, "mockup.markers.")
    return tuple(tuple(map(float, inner.vector(str(i), 3))) for i in range(len(markers)))


def _keypoints(f: Fields) -> tuple[tuple[float, float, float], ...] | None:
    if not f.optional("keypoints"):
        return None
    keypoints = f.child("keypoints")
    keypoints.only("points")
    points = keypoints.raw("points")
    if not isinstance(points, list) or len(points) < MIN_KEYPOINTS:
        raise keypoints.fail("points", f"a list of at least {MIN_KEYPOINTS} [x, y, z] points")
    inner = Fields({str(i): p for i, p in enumerate(points)}, keypoints.where, "keypoints.points.")
    return tuple(tuple(map(float, inner.vector(str(i), 3))) for i in range(len(points)))


def _views(f: Fields) -> tuple[tuple[float, float, float] | None, tuple[str, str] | None]:
    if not f.optional("views"):
        return None, None
    views = f.child("views")
    views.only("axis", "names")
    axis = views.vector("axis", 3)
    if math.sqrt(sum(v * v for v in axis)) < 1e-9:
        raise views.fail("axis", "a non-zero direction")
    names = views.raw("names")
    if (not isinstance(names, list) or len(names) != 2 or not all(isinstance(n, str) for n in names)
            or names[0] == names[1] or not all(NAME_PATTERN.fullmatch(n) for n in names) or "all" in names):
        raise views.fail("names", "two different names of a-z, 0-9, _ and - (positive side first; not \"all\", "
                                  "which Table 2 uses for both)")
    return tuple(map(float, axis)), (names[0], names[1])


def _symmetries(f: Fields) -> tuple[tuple[tuple[float, ...], ...], tuple[tuple[tuple[float, float, float],
                                                                              tuple[float, float, float]], ...]]:
    """BOP's symmetries, checked as transforms (``load_target`` checks them on the mesh)."""
    if not f.optional("symmetries"):
        return (), ()
    symmetries = f.child("symmetries")
    symmetries.only("discrete", "continuous")
    for name in ("discrete", "continuous"):
        if symmetries.optional(name) and not isinstance(symmetries.raw(name), list):
            raise symmetries.fail(name, "a list")
    discrete = []
    for index, matrix in enumerate(symmetries.raw("discrete") if symmetries.optional("discrete") else []):
        key = f"discrete.{index}"
        numbers = isinstance(matrix, list) and all(isinstance(v, int | float) and not isinstance(v, bool)
                                                   for v in matrix)
        if not numbers or len(matrix) != 16 or not np.all(np.isfinite(matrix)):
            raise symmetries.fail(key, "16 finite numbers: a 4 x 4 transform, row-major")
        transform = np.asarray(matrix, float).reshape(4, 4)
        rotation = transform[:3, :3]
        if (not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6) or np.linalg.det(rotation) < 0
                or not np.array_equal(transform[3], [0, 0, 0, 1])):
            raise symmetries.fail(key, "a rigid transform (an orthonormal rotation, last row 0 0 0 1)")
        discrete.append(tuple(float(v) for v in matrix))
    continuous = []
    for index, entry in enumerate(symmetries.raw("continuous") if symmetries.optional("continuous") else []):
        if not isinstance(entry, dict):
            raise symmetries.fail(f"continuous.{index}", "a table { axis = [x, y, z], offset = [x, y, z] }")
        item = Fields(entry, symmetries.where, f"{symmetries.key('continuous')}.{index}.")
        item.only("axis", "offset")
        axis = item.vector("axis", 3)
        if math.sqrt(sum(v * v for v in axis)) < 1e-9:
            raise item.fail("axis", "a non-zero direction")
        offset = item.vector("offset", 3) if item.optional("offset") else (0.0, 0.0, 0.0)
        continuous.append((tuple(map(float, axis)), tuple(map(float, offset))))
    return tuple(discrete), tuple(continuous)


def _looks(f: Fields) -> dict[str, Look]:
    if not f.optional("looks"):
        return {}
    looks = f.child("looks")
    out = {}
    for part, value in looks.data.items():
        if isinstance(value, str):
            out[part] = Look(*(looks.text(part, LOOK_PRESETS),) * 2)
            continue
        entry = looks.child(part)
        entry.only("synthetic", "mockup")
        out[part] = Look(entry.text("synthetic", LOOK_PRESETS), entry.text("mockup", LOOK_PRESETS))
    return out
