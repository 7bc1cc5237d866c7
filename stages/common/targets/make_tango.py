"""Writes the built-in Tango target folder (``tango/``: ``target.toml`` and ``tango.glb``)
from the procedural mesh and the 11 SPEED+ keypoints (``stages.common.tango``):

    python -m stages.common.targets.make_tango

The body centre is declared (the centre of the body box, not of the antennas' reach), so
that the view rule and the planner's sphere stay those of ``stages.common.tango``."""

from __future__ import annotations

import math
from pathlib import Path

from manifests.files import write_bytes_atomic
from manifests.schema import VIEWS
from manifests.sidecars.base import Pose
from manifests.target import Look, TargetSpec, write_target_spec
from stages.common.tango import BODY_CENTRE_M, KEYPOINTS_M
from stages.common.tango_mesh import tango_parts
from stages.common.targets import BUILTIN_ROOT

MESH = "tango.glb"
#: (synthetic, mock-up) looks: the flight model's radiator is white paint and its antennas
#: metal; TRON's mock-up has a bare aluminium rear plate and painted antennas
LOOKS = {"sides": ("gold_mli", "gold_mli"), "solar_panel": ("solar_cells", "solar_cells"),
         "rear_panel": ("white_paint", "aluminium"), "antennas": ("aluminium", "white_paint")}


def mesh_bytes() -> bytes:
    """The procedural parts as one GLB, a node per part (vertices become float32)."""
    import trimesh

    scene = trimesh.Scene()
    for name, part in tango_parts().items():
        mesh = trimesh.Trimesh(part.vertices, part.faces, process=False,
                               visual=trimesh.visual.TextureVisuals(uv=part.uv))
        scene.add_geometry(mesh, geom_name=name, node_name=name)
    return scene.export(file_type="glb")


#: TRON's half-scale mock-up, full scale here (the mock-up's lengths doubled, exactly): the
#: minus_x fixture's flange 12 cm (on the mock-up) off the -x face, 8 cm up; the board on
#: the solar panel on a 3 mm plate, its 11 x 30 mm squares centred
SCALE = 0.5
FIXTURE = Pose((0.0, math.sqrt(0.5), 0.0, math.sqrt(0.5)), (-0.305 / SCALE, 0.0, 0.08 / SCALE))
BOARD = Pose((0.0, 1.0, 0.0, 0.0), (-0.165 / SCALE, 0.165 / SCALE, 0.16375 / SCALE))
#: the six motion-capture markers TRON-like rigid bodies use, full scale: on the top (+z)
#: near three corners, on the +x and -x sides and on the slanted +y side, each about 1 cm
#: (on the mock-up) off the body
MARKERS = ((0.333, 0.308, 0.324715), (-0.333, 0.32725, 0.324715), (0.3145, -0.3465, 0.324715),
           (0.3811, 0.077, 0.241125), (-0.3811, -0.1155, 0.208975), (0.074, 0.39655, 0.1929))


def spec() -> TargetSpec:
    return TargetSpec("tango", MESH, "m", SCALE, 4.0, centre=tuple(float(v) for v in BODY_CENTRE_M),
                      keypoints=tuple(tuple(float(v) for v in p) for p in KEYPOINTS_M), view_axis=(0.0, 0.0, 1.0),
                      view_names=(VIEWS[0], VIEWS[1]), looks={part: Look(*looks) for part, looks in LOOKS.items()},
                      fixture=FIXTURE, board=BOARD, markers=MARKERS)


def main(folder: Path = BUILTIN_ROOT / "tango") -> None:
    folder.mkdir(parents=True, exist_ok=True)
    write_bytes_atomic(folder / MESH, mesh_bytes())
    write_target_spec(folder, spec())
    print(f"wrote {folder}")


if __name__ == "__main__":
    main()
