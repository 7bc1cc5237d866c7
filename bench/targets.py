"""Four strangers' targets for ``bench honesty --target``, made with trimesh as a lab would
export its own mock-up (issue 43). They were chosen, and committed, before the change they
judge (motion capture's sigma from its marker layout, the evidence-based fall-back, the
short-session sigmas), and differ in shape, size, scale, mass, file format and unit:

========== ============================================== ===== ====== ====== =======
name       shape                                          scale mass   format unit
========== ============================================== ===== ====== ====== =======
bus_panels 0.32 m cube bus, two thin panels spanning 1 m  1:1   3 kg   GLB    m
cubesat3u  3U CubeSat, 0.1 x 0.1 x 0.34 m, two whips      1:1   1.2 kg GLB    mm
asteroid   lumpy irregular body, 1.0 m full scale         1:2   9 kg   PLY    mm
rocket     upper stage: cylinder and nozzle, 3.2 m long   1:4   5 kg   STL    m
========== ============================================== ===== ====== ====== =======

None declares its markers: the testbed chooses them (``stages.common.markers``), as it
would for a lab that has not yet stuck any.

    python -m bench targets [ROOT]   (writes the four folders under ROOT, default data/targets)
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh

from manifests.target import TargetSpec, write_target_spec

NAMES = ("bus_panels", "cubesat3u", "asteroid", "rocket")


def bus_panels(folder: Path) -> Path:
    """A 0.32 m cube bus with two 0.34 x 0.25 m panels on booms, 1.0 m tip to tip, 3 kg."""
    scene = trimesh.Scene()
    scene.add_geometry(trimesh.creation.box((0.32, 0.32, 0.32)), geom_name="bus", node_name="bus")
    for side, name in ((-1, "panel_minus"), (1, "panel_plus")):
        panel = trimesh.creation.box((0.34, 0.25, 0.004))
        panel.apply_translation((side * (0.16 + 0.17), 0.0, 0.0))
        scene.add_geometry(panel, geom_name=name, node_name=name)
    return _write(folder, "bus_panels", "bus.glb", scene.export(file_type="glb"), "m", 1.0, 3.0)


def cubesat3u(folder: Path) -> Path:
    """A 3U CubeSat (100 x 100 x 340 mm) with two 150 mm whip antennas, in mm, 1.2 kg."""
    scene = trimesh.Scene()
    scene.add_geometry(trimesh.creation.box((100.0, 100.0, 340.0)), geom_name="body", node_name="body")
    for side, name in ((-1, "whip_minus"), (1, "whip_plus")):
        whip = trimesh.creation.cylinder(radius=2.0, height=150.0)
        whip.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (0, 1, 0)))
        whip.apply_translation((side * (50.0 + 75.0), 0.0, 160.0))
        scene.add_geometry(whip, geom_name=name, node_name=name)
    return _write(folder, "cubesat3u", "cubesat.glb", scene.export(file_type="glb"), "mm", 1.0, 1.2)


def asteroid(folder: Path) -> Path:
    """A lumpy body about 1.0 x 0.75 x 0.6 m full scale (a seeded sum of bumps on an
    ellipsoid), one PLY in mm; mock-up 1:2, 9 kg."""
    rock = trimesh.creation.icosphere(subdivisions=3, radius=500.0)
    rng = np.random.default_rng(43)
    directions = rng.normal(size=(12, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    unit = rock.vertices / np.linalg.norm(rock.vertices, axis=1, keepdims=True)
    bumps = np.exp((unit @ directions.T - 1.0) / 0.08) @ rng.uniform(-0.25, 0.3, size=12)
    rock.vertices = unit * (500.0 * (1.0 + bumps))[:, None] * [1.0, 0.75, 0.6]
    return _write(folder, "asteroid", "asteroid.ply", rock.export(file_type="ply"), "mm", 0.5, 9.0)


def rocket(folder: Path) -> Path:
    """An upper stage, 3.2 m long and 0.9 m across with a nozzle cone, one STL in metres;
    mock-up 1:4, 5 kg."""
    tank = trimesh.creation.cylinder(radius=0.45, height=2.6, sections=48)
    nozzle = trimesh.creation.cone(radius=0.35, height=0.6, sections=48)
    nozzle.apply_transform(trimesh.transformations.rotation_matrix(np.pi, (1, 0, 0)))
    nozzle.apply_translation((0.0, 0.0, -1.3))
    stage = trimesh.util.concatenate([tank, nozzle])
    stage.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (0, 1, 0)))  # long axis on x
    return _write(folder, "rocket", "rocket.stl", stage.export(file_type="stl"), "m", 0.25, 5.0)


def _write(folder: Path, name: str, mesh: str, data: bytes, unit: str, scale: float, mass_kg: float) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / mesh).write_bytes(data)
    write_target_spec(folder, TargetSpec(name, mesh, unit, scale, mass_kg))
    return folder


MAKERS = {"bus_panels": bus_panels, "cubesat3u": cubesat3u, "asteroid": asteroid, "rocket": rocket}


def write_all(root: Path) -> dict[str, Path]:
    """The four target folders under ``root``, by name."""
    return {name: make(root / name) for name, make in MAKERS.items()}


def main(root: str = "data/targets") -> None:
    for name, folder in write_all(Path(root)).items():
        print(f"{name}: {folder}")


if __name__ == "__main__":
    main(*sys.argv[1:])
