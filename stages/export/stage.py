"""The export stage's ``run`` and ``resolve`` (what the stage does: the package's docstring).

Every image written is a row of the ``export_<format>`` manifest (key ``<set>/<sample_id>``),
so an interrupted export resumes with the images it lacks; the annotation files are
written last, from every item.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path, PurePosixPath
from typing import Any

import pyarrow as pa

from core.config import Config
from core.progress import track
from core.stage_io import Resolved
from manifests import Workspace, list_parts, open_sink, read_keys, read_manifest, read_marker
from manifests.facility import facility_digest
from manifests.files import copy_atomic, write_json_atomic
from manifests.schema import DOMAINS
from manifests.sidecars import read_session, read_trajectories
from manifests.workspace import EXPORT_DIR, PathEscapeError, check_relative
from speedplus.errors import InputError
from stages.common.cameras import train_camera
from stages.common.json_arrays import calibrated_camera
from stages.common.lens import LensCamera
from stages.common.robots.facility import load_facility
from stages.common.workspace_target import workspace_target
from stages.export import bop, robot, rosbag, session, shirt, speedplus
from stages.export.config import EXPORT_FORMATS

#: in the export folder: whose export it is (the devkits and bop_toolkit ignore hidden files);
#: {"version": EXPORT_MARK_VERSION, "workspace": W, "format": ...}, compared whole
EXPORT_MARK = ".speedplus-export.json"
EXPORT_MARK_VERSION = 1


def resolve(config: Config, workspace: Workspace | None = None) -> Resolved:
    """Per ``export.sets`` the labels with their captures, renders or the training set (and a
    trajectory plan's sequences); one output manifest per format, so the exports coexist.
    The robot programs read the plan alone, and time its moves as the virtual testbed does."""
    if config.export.format in ("session", "rosbag"):
        return Resolved(("captures",), ("export.format", "export.out"), {}, (f"export_{config.export.format}",))
    if config.export.format == "robot":
        timing = ("virtual.speed_override", "virtual.rail_speed_m_s", "virtual.light_change_s")
        extra = {"facility": facility_digest(Path(config.facility.path))} if config.facility.path else {}
        return Resolved(("plan",), ("export.format", "export.out", "facility.path", *timing), extra, ("export_robot",))
    inputs = {"testbed": ("labels", "captures"), "twins": ("labels", "renders"), "train": ("train",)}
    needed = tuple(dict.fromkeys(name for chosen in config.export.sets for name in inputs[chosen]))
    if config.plan.mode == "trajectory":  # each image's sequence and frame
        needed = ("plan", *needed)
    # of the render section, only what sizes the training camera matters here
    train = ("render.train_resolution_scale",) if "train" in config.export.sets else ()
    return Resolved(needed, ("export", "camera", "plan.mode", *train), {}, (f"export_{config.export.format}",))


def out_dir(config: Config, workspace: Workspace) -> Path:
    """``export.out``, else ``W/export/<format>``."""
    if config.export.out:
        return Path(config.export.out).resolve()
    return workspace.root / EXPORT_DIR / config.export.format


def status_views(config: Config, workspace: Workspace) -> list[tuple[str, Config]]:
    """One (label, configuration) per format this workspace has exported, each with the
    folder its marker recorded, so that ``status`` reports every export, not only the
    configured one; the configured format alone when none has results."""
    views = []
    for export_format in EXPORT_FORMATS:
        name = f"export_{export_format}"
        marker = read_marker(workspace, name)
        if marker is None and not list_parts(workspace, name):
            continue
        made = (marker.made_with or {}) if marker else {}
        recorded = made.get("config", {}).get("export", {}) if isinstance(made, dict) else {}
        section = replace(config.export, format=export_format, out=recorded.get("out", config.export.out),
                          sets=tuple(recorded.get("sets", config.export.sets)))
        views.append((f"export {export_format}", config.replace(export=section)))
    return views or [(f"export {config.export.format}", config)]


def inside_export(file: str, item: dict[str, Any]) -> PurePosixPath:
    """``file`` (from the labels' filename) as a path that stays inside the export folder."""
    try:
        return check_relative(file)
    except PathEscapeError:
        raise InputError(f"labels: sample {item['sample_id']}: filename {item['filename']!r} would leave the "
                         "export folder; relabel with a plain label.filename_template") from None


def claim(out: Path, workspace: Workspace, export_format: str) -> None:
    """Make ``out`` this workspace's export folder in ``export_format``: it must be empty, or
    an export of this workspace in this format (a resumed, repeated or forced export). Even
    ``--force`` never writes into another format's export or a folder of the user's."""
    mark = out / EXPORT_MARK
    ours = {"version": EXPORT_MARK_VERSION, "workspace": workspace.location, "format": export_format}
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: export.out is a file, not a folder")
    if out.is_dir() and any(out.iterdir()):
        try:
            theirs = json.loads(mark.read_text())
        except (OSError, ValueError):
            theirs = None
        # a folder inside the workspace is its own, wherever the workspace was when it was written
        inside = workspace.remote is None and out.resolve().is_relative_to(workspace.root.resolve())
        if inside and isinstance(theirs, dict):
            theirs = {**theirs, "workspace": workspace.location}
        if theirs != ours:
            what = (f"a {theirs.get('format')} export of {theirs.get('workspace')}" if isinstance(theirs, dict)
                    else "files speedplus did not write")
            raise InputError(f"{out}: not empty: it holds {what}, not a {export_format} export of "
                             f"{workspace.location}, and an export replaces only its own (even with --force); "
                             f"choose an empty folder with --out, or leave --out out for "
                             f"{workspace.location}/export/{export_format}")
    write_json_atomic(mark, ours)


def items(config: Config, workspace: Workspace) -> list[dict[str, Any]]:
    """Every image to export, in export_id order: export_id, sample_id, set, domain,
    filename, source (W-relative), the pose (q_vbs2tango_true, r_Vo2To_vbs_true, full
    scale) and, for BOP, scene_id and im_id."""
    out: list[dict[str, Any]] = []
    labels = sorted(read_manifest(workspace, "labels").to_pylist(), key=lambda r: r["sample_id"]) \
        if {"testbed", "twins"} & set(config.export.sets) else []
    sources: dict[str, dict[str, str]] = {}
    if "testbed" in config.export.sets:
        sources["testbed"] = {r["sample_id"]: r["image_path"] for r in read_manifest(workspace, "captures").to_pylist()}
    if "twins" in config.export.sets:
        sources["twins"] = {r["sample_id"]: r["image_path"] for r in read_manifest(workspace, "renders").to_pylist()}
    frames = sequence_frames(config, workspace)
    for export_set in ("testbed", "twins"):
        if export_set not in sources:
            continue
        index = dict.fromkeys(DOMAINS, 0)
        for label in labels:
            source = sources[export_set].get(label["sample_id"])
            if source is None and export_set == "testbed":
                raise InputError(f"labels: sample {label['sample_id']} has no row in the captures manifest")
            if source is None:  # a twin that could not be rendered (render's rejected.json says why)
                continue
            frame = frames.get(label["sample_id"], {})
            if frame:  # a sequence is a scene of its own, its frames the image ids
                scene_id, im_id = frame["scene_id"], frame["frame"]
            else:
                scene_id, im_id = bop.place(export_set, label["domain"], index[label["domain"]])
                index[label["domain"]] += 1
            out.append({"set": export_set, "sample_id": label["sample_id"], "domain": label["domain"],
                        "filename": label["filename"], "source": source, "scene_id": scene_id, "im_id": im_id,
                        "q_vbs2tango_true": label["q_vbs2tango_true"], "r_Vo2To_vbs_true": label["r_Vo2To_vbs_true"],
                        **frame})
    if "train" in config.export.sets:
        train = sorted(read_manifest(workspace, "train").to_pylist(), key=lambda r: r["sample_id"])
        for index, row in enumerate(train):
            scene_id, im_id = bop.place("train", "synthetic", index)
            out.append({"set": "train", "sample_id": row["sample_id"], "domain": "synthetic",
                        "filename": f"{row['sample_id']}.png", "source": row["image_path"], "scene_id": scene_id,
                        "im_id": im_id, "q_vbs2tango_true": row["q_vbs2tango_true"],
                        "r_Vo2To_vbs_true": row["r_Vo2To_vbs_true"]})
    for item in out:
        item["export_id"] = f"{item['set']}/{item['sample_id']}"
    return sorted(out, key=lambda item: item["export_id"])


def sequence_frames(config: Config, workspace: Workspace) -> dict[str, dict[str, Any]]:
    """sample_id -> its sequence_id, frame, time_s and BOP scene (the sequence's place in
    the plan, from 1), for a trajectory plan; empty otherwise."""
    if config.plan.mode != "trajectory":  # (a shirt export without sequences is refused with the configuration)
        return {}
    rows = sorted(read_manifest(workspace, "plan").select(["sample_id", "sequence_id", "frame", "time_s"]).to_pylist(),
                  key=lambda r: r["sample_id"])
    scenes = {name: i + 1 for i, name in enumerate(dict.fromkeys(r["sequence_id"] for r in rows
                                                                 if r["sequence_id"] is not None))}
    return {r["sample_id"]: {"sequence_id": r["sequence_id"], "frame": r["frame"], "time_s": r["time_s"],
                             "scene_id": scenes[r["sequence_id"]]}
            for r in rows if r["sequence_id"] is not None}


def cameras(config: Config, workspace: Workspace) -> dict[str, LensCamera]:
    """The camera of each exported set: the calibrated one for the testbed and the twins
    (render draws them with it), the training camera for the training set."""
    out = {}
    if {"testbed", "twins"} & set(config.export.sets):
        out["testbed"] = out["twins"] = calibrated_camera(workspace)
    if "train" in config.export.sets:
        out["train"] = train_camera(config)
    return out


def run(config: Config, workspace: Workspace) -> pa.Table:
    """Write every item missing from the manifest, then the annotation files."""
    out, name = out_dir(config, workspace), f"export_{config.export.format}"
    if config.export.format == "robot":
        return robot_programs(config, workspace, out)
    if config.export.format == "session":
        return session_layout(config, workspace, out)
    if config.export.format == "rosbag":
        return rosbag_layout(workspace, out)
    claim(out, workspace, config.export.format)
    chosen, by_set = items(config, workspace), cameras(config, workspace)
    if config.export.format == "speedplus" and "train" in by_set:
        speedplus.check_one_camera(by_set["testbed"] if "testbed" in by_set else by_set["train"], by_set["train"])
    done = read_keys(workspace, name)
    todo = [item for item in chosen if item["export_id"] not in done]
    target = workspace_target(config, workspace)
    surfaces = bop.TargetSurfaces(target.parts) if config.export.format == "bop" and todo else None
    with open_sink(workspace, name, config.run.part_rows) as sink:
        for item in track(todo, len(todo), "export"):
            source = workspace.fetch(item["source"])
            if config.export.format in ("speedplus", "shirt"):
                file = (speedplus.image_file(item["set"], item["domain"], item["filename"])
                        if config.export.format == "speedplus" else shirt.image_file(item))
                copy_atomic(source, out / inside_export(file, item))
            else:
                file = bop.write_image(out, item, source, by_set[item["set"]], surfaces)
            sink.add({"export_id": item["export_id"], "sample_id": item["sample_id"], "set": item["set"],
                      "domain": item["domain"], "file": file, "source_image": item["source"]})
    if config.export.format in ("speedplus", "shirt"):
        labels_camera = by_set.get("testbed") or by_set["train"]
        pitch = config.camera.pixel_pitch_m * config.camera.reference_width_px / labels_camera.width
        camera = speedplus.camera_json(labels_camera, pitch)
        if config.export.format == "speedplus":
            counts = speedplus.write_annotations(out, chosen, camera, config.export.validation_fraction)
        else:
            counts = shirt.write_annotations(out, chosen, camera, read_trajectories(workspace))
        speedplus.write_keypoints(out, target.name, target.keypoints_m)
    else:
        counts = bop.write_annotations(out, chosen, by_set, target)
    print(f"export: {', '.join(f'{v} in {k}' for k, v in counts.items())} ({config.export.format}) in {out}")
    return read_manifest(workspace, name)


def robot_programs(config: Config, workspace: Workspace, out: Path) -> pa.Table:
    """The plan as each robot's waypoints (the ``export_robot`` rows) and its programs, in
    the order ``stages.export.robot.ordered`` gives; the files are written last, from every row."""
    facility = load_facility(Path(config.facility.path) if config.facility.path else None)  # the plan's room
    timing = robot.Timing(config.virtual.speed_override, config.virtual.rail_speed_m_s, config.virtual.light_change_s)
    planned = robot.waypoints(read_manifest(workspace, "plan").to_pylist(), facility)
    points = robot.ordered(planned, facility, timing)
    claim(out, workspace, "robot")  # once the plan is known to be this facility's
    done = read_keys(workspace, "export_robot")
    with open_sink(workspace, "export_robot", config.run.part_rows) as sink:
        for member in facility.robots:
            for step, point in enumerate(points, start=1):
                key = f"{member.spec.name}/{step:06d}"
                if key in done:
                    continue
                joints, rail_m = point.commands[member.spec.name]
                sink.add({"waypoint_id": key, "robot": member.spec.name, "step": step, "sample_id": point.sample_id,
                          "session": point.session, "capture": True, "joints_rad": [float(v) for v in joints],
                          "rail_m": rail_m})
    times = robot.write_programs(out, facility, points, timing, robot.session_s(planned, facility, timing))
    print(f"export: {len(points)} waypoints for {', '.join(r.spec.name for r in facility.robots)} (robot) in {out}; "
          f"moves and light changes {times['moves_s'] / 60:.1f} min, {times['plan_order_moves_s'] / 60:.1f} in the "
          "plan's order")
    for member in (r for r in facility.robots if r.spec.controller not in robot.PROGRAMS):
        print(f"export: {member.spec.name}: its joint waypoints only ({member.spec.name}.csv, .json): facility.toml "
              f"gives it controller {member.spec.controller!r}; a program is written for controller "
              f"{' or '.join(f'{c} ({language})' for c, language in robot.PROGRAMS.items())}")
    return read_manifest(workspace, "export_robot")


def session_layout(config: Config, workspace: Workspace, out: Path) -> pa.Table:
    """The captures as a logger's session folder (``stages.export.session``): every image
    missing from the ``export_session`` manifest, then the tables, from every capture."""
    captures = sorted(read_manifest(workspace, "captures").to_pylist(),
                      key=lambda row: (row["session"] != "calibration", row["sample_id"]))
    recorded = read_session(workspace)
    claim(out, workspace, "session")
    done = read_keys(workspace, "export_session")
    with open_sink(workspace, "export_session", config.run.part_rows) as sink:
        todo = [r for r in captures if f"{r['session']}/{r['sample_id']}" not in done]
        for row in track(todo, len(todo), "export"):
            file = session.image_file(row)
            try:
                relative = check_relative(file)
            except PathEscapeError:
                raise InputError(f"captures: sample {row['sample_id']}: {file!r} leaves the export folder") from None
            copy_atomic(workspace.fetch(row["image_path"]), out / relative)
            sink.add({"export_id": f"{row['session']}/{row['sample_id']}", "sample_id": row["sample_id"],
                      "session": row["session"], "file": file, "source_image": row["image_path"]})
    session.write_tables(out, recorded, captures)
    print(f"export: {len(captures)} captures as a logger's session (session) in {out}; replay it with `speedplus "
          f"acquire -w W2 --backend replay --format session --source {out}`")
    return read_manifest(workspace, "export_session")


def rosbag_layout(workspace: Workspace, out: Path) -> pa.Table:
    """The captures as a ROS 2 bag and its mapping (``stages.export.rosbag``): one file,
    written whole (an interrupted export writes it again), then its rows."""
    captures = sorted(read_manifest(workspace, "captures").to_pylist(),
                      key=lambda row: (row["session"] != "calibration", row["sample_id"]))
    claim(out, workspace, "rosbag")

    def image(row: dict[str, Any]) -> tuple[bytes, str]:
        return workspace.fetch(row["image_path"]).read_bytes(), PurePosixPath(row["image_path"]).suffix[1:]

    stamps = rosbag.write_bag(out, read_session(workspace), captures, image)
    done = read_keys(workspace, "export_rosbag")
    with open_sink(workspace, "export_rosbag", len(captures) or 1) as sink:
        for row, stamp in zip(captures, stamps, strict=True):
            if f"{row['session']}/{row['sample_id']}" not in done:
                sink.add({"export_id": f"{row['session']}/{row['sample_id']}", "sample_id": row["sample_id"],
                          "session": row["session"], "stamp_ns": stamp, "source_image": row["image_path"]})
    print(f"export: {len(captures)} captures as a ROS 2 bag (rosbag, MCAP) in {out / rosbag.BAG_DIR}; replay it "
          f"with `speedplus acquire -w W2 --backend replay --format rosbag --source {out / rosbag.BAG_DIR}`")
    return read_manifest(workspace, "export_rosbag")
