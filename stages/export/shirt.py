"""SHIRT's layout (Park and D'Amico's rendezvous sequences), for a trajectory plan::

    OUT/<sequence>/metadata.json                 cam_step (s), num_images, camera, and the
                                                 sequence's orbit, relative orbit, inertia and spin
    OUT/<sequence>/synthetic/images/<filename>   the twins           OUT/<sequence>/synthetic.json
    OUT/<sequence>/lightbox/images/<filename>    testbed, light boxes OUT/<sequence>/lightbox.json
    OUT/<sequence>/sunlamp/images/<filename>     testbed, sun lamp    OUT/<sequence>/sunlamp.json
    OUT/tangoPoints.mat, OUT/keypoints.json      the target's keypoints (as for SPEED+)

A domain's json lists its frames in frame order: ``{filename, q_vbs2tango_true,
r_Vo2To_vbs_true, time_s, frame}`` with SPEED+'s conventions (the rotation of
``cam_from_target``, the translation in metres, full scale). A testbed frame is in the
domain of the light it was taken under (plan.light), so each testbed json may skip frames;
``time_s`` and ``frame`` say where each one sits. ``camera`` is SPEED+'s camera.json.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from manifests.files import write_json_atomic
from manifests.sidecars import TrajectoriesRecord

METADATA_VERSION = 1
TWINS_DOMAIN = "synthetic"


def domain(item: dict[str, Any]) -> str:
    return TWINS_DOMAIN if item["set"] == "twins" else item["domain"]


def image_file(item: dict[str, Any]) -> str:
    """Where an item's image goes, relative to the export folder."""
    return f"{item['sequence_id']}/{domain(item)}/images/{item['filename']}"


def write_annotations(out: Path, items: list[dict[str, Any]], camera: dict[str, Any],
                      trajectories: TrajectoriesRecord) -> dict[str, int]:
    """Every sequence's ``metadata.json`` and domain jsons from the export items (with
    sequence_id, frame, time_s); counts per file."""
    files: dict[str, list[tuple[int, dict[str, Any]]]] = {}
    for item in items:
        entry = {"filename": item["filename"], "q_vbs2tango_true": [float(v) for v in item["q_vbs2tango_true"]],
                 "r_Vo2To_vbs_true": [float(v) for v in item["r_Vo2To_vbs_true"]], "time_s": float(item["time_s"]),
                 "frame": int(item["frame"])}
        files.setdefault(f"{item['sequence_id']}/{domain(item)}.json", []).append((item["frame"], entry))
    for sequence in trajectories.sequences:
        record = sequence.to_json()
        write_json_atomic(out / sequence.sequence_id / "metadata.json", {
            "version": METADATA_VERSION, "cam_step": sequence.cam_step_s, "num_images": sequence.frames,
            "camera": camera, **{key: value for key, value in record.items() if key != "first_sample_id"}})
    for key, entries in sorted(files.items()):
        write_json_atomic(out / key, [entry for _, entry in sorted(entries, key=lambda pair: pair[0])])
    return {key: len(entries) for key, entries in sorted(files.items())}
