"""A reference model of a target nobody tuned the recipe on: an asymmetric satellite of
four parts (a gold box, one solar wing, a dish, a boom; 0.72 m, no keypoints: 11 chosen on
its hull), made here with trimesh. ``train-reference`` renders its training set and trains
on it with a profile's recipe; the model card's held-out synthetic accuracy is printed.

    python -m bench stranger_model [PROFILE] [VARIANT] [ROOT]
        (default: default plain data/stranger_model; the default recipe took 49 min for the
        plain variant on 2 cores, 28 rendering and 21 training; smoke's about two minutes)

Distances are SPEED+'s training range in target diameters (3-10 m of Tango's 1.37 m).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

from bench.common import report
from manifests.target import Look, TargetSpec, write_target_spec


def satellite(folder: Path) -> Path:
    """The asymmetric satellite's target folder (a GLB of four named parts, metres)."""
    import trimesh

    folder.mkdir(parents=True, exist_ok=True)
    scene = trimesh.Scene()
    scene.add_geometry(trimesh.creation.box((0.1, 0.226, 0.366)), geom_name="body", node_name="body")
    wing = trimesh.creation.box((0.226, 0.004, 0.366))
    wing.apply_translation((0.163, 0.113, 0.0))
    scene.add_geometry(wing, geom_name="wing", node_name="wing")
    dish = trimesh.creation.cylinder(radius=0.08, height=0.02)
    dish.apply_translation((0.0, 0.0, 0.193))
    scene.add_geometry(dish, geom_name="dish", node_name="dish")
    boom = trimesh.creation.box((0.02, 0.02, 0.25))
    boom.apply_translation((-0.04, -0.09, -0.3))
    scene.add_geometry(boom, geom_name="boom", node_name="boom")
    (folder / "satellite.glb").write_bytes(scene.export(file_type="glb"))
    looks = {"body": "gold_mli", "wing": "solar_cells", "dish": "white_paint", "boom": "aluminium"}
    write_target_spec(folder, TargetSpec("asymmetric_satellite", "satellite.glb", "m", 1.0, 6.0,
                                         looks={part: Look(look, look) for part, look in looks.items()}))
    return folder


def main(profile: str = "default", variant: str = "plain", root: str = "data/stranger_model") -> None:
    base = Path(root)
    folder = satellite(base / "target")
    started = time.perf_counter()
    result = subprocess.run(
        [sys.executable, "-m", "pipeline.cli", "train-reference", "--profile", profile, "--workspace", str(base / "w"),
         "--out", str(base / "models"), "--set", f"target.path={folder.resolve()}",
         "--set", "render.train_distance_m=[0, 1e9]", "--set", "render.train_distance_diameters=[2.2, 7.3]",
         "--set", f'reference.variants=["{variant}"]'], check=False)
    if result.returncode != 0:
        sys.exit(result.returncode)
    name = "reference" if variant == "plain" else "reference_augmented"
    card = json.loads((base / "models" / f"{name}.json").read_text())
    held = card["held_out"]
    report("stranger_model", f"a {profile}-profile {variant} model of an asymmetric satellite nobody tuned on",
           [{"profile": profile, "variant": variant, "training images": card["training_images"],
             "held-out images": card["held_out_images"], "train s": card["train_seconds"],
             "render and train s": round(time.perf_counter() - started, 1),
             "mean SPEED": held["mean_speed_score"],
             "median rotation error (deg)": held["median_rotation_error_deg"],
             **{key: value for key, value in held.items()
                if key not in ("mean_speed_score", "median_rotation_error_deg", "images")}}])
