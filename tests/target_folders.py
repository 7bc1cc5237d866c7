"""Two strangers' targets for the tests, made here with trimesh as a lab would export
them: a 6U CubeSat (GLB of named parts, millimetres, its long axis on the mesh's x, no
keypoints) and a boulder (a single STL in metres with declared keypoints and views)."""

from pathlib import Path

import numpy as np
import trimesh

from manifests.sidecars.base import Pose
from manifests.target import TargetSpec, write_target_spec
from stages.common import geometry as g

BOULDER_KEYPOINTS = [[0.4, 0, 0], [-0.4, 0, 0], [0, 0.32, 0], [0, 0, 0.24], [0, 0, -0.24]]


def cubesat(folder: Path, unit: str = "mm", mass_kg: float = 9.0, **fields) -> Path:
    """A 6U CubeSat (100 x 226 x 366 mm body, two 366 x 226 mm wings) as a GLB of named
    parts, in mm, with its long axis along the mesh's x (the body frame wants it on z);
    ``mass_kg``: a flight 6U's by default."""
    folder.mkdir(parents=True, exist_ok=True)
    scene = trimesh.Scene()
    scene.add_geometry(trimesh.creation.box((366.0, 226.0, 100.0)), geom_name="body", node_name="body")
    for side in (-1, 1):
        wing = trimesh.creation.box((366.0, 2.0, 226.0))
        wing.apply_translation((0.0, side * 113.0, 163.0))
        scene.add_geometry(wing, geom_name=f"wing_{'minus' if side < 0 else 'plus'}",
                           node_name=f"wing_{'minus' if side < 0 else 'plus'}")
    (folder / "cubesat.glb").write_bytes(scene.export(file_type="glb"))
    turn = g.matrix_to_quat(g.axis_angle_matrix("y", -np.pi / 2))  # mesh x -> body z
    write_target_spec(folder, TargetSpec("cubesat6u", "cubesat.glb", unit, 1.0, mass_kg,
                                         body_from_mesh=Pose(tuple(float(v) for v in turn), (0.0, 0.0, 0.0)),
                                         **fields))
    return folder


def boulder(folder: Path, mass_kg: float = 3.0) -> Path:
    """An ellipsoidal boulder 0.8 x 0.64 x 0.48 m as one STL, keypoints and views declared; a
    hollow replica's mass (a solid 12 kg one tilts TRON's fixture by 3.5 deg, beyond its
    first-order sag model)."""
    folder.mkdir(parents=True, exist_ok=True)
    rock = trimesh.creation.icosphere(subdivisions=2, radius=0.4)
    rock.vertices *= [1.0, 0.8, 0.6]
    rock.export(folder / "boulder.stl")
    write_target_spec(folder, TargetSpec("boulder", "boulder.stl", "m", 1.0, mass_kg, keypoints=BOULDER_KEYPOINTS,
                                         view_axis=(1.0, 0.0, 0.0), view_names=("east", "west")))
    return folder
