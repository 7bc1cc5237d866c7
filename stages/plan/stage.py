"""The plan stage's ``run`` and ``resolve`` (what the stage does: the package's docstring).

Every sample is drawn from its own random stream ``(seed, session, index)``, so the plan
is identical for a seed whatever order (or how many runs) it is produced in: a resumed
run regenerates exactly the missing rows.
"""

from __future__ import annotations

import dataclasses
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa

from core.config import Config, TestbedConfig
from core.progress import track
from core.stage_io import Resolved
from manifests import Workspace, open_sink, read_keys, read_manifest, sample_ids
from manifests.facility import StaticSpec, facility_digest, read_facility_spec
from manifests.sample_ids import SESSION_CODES
from manifests.sidecars import TrajectoriesRecord, write_trajectories
from stages.common import geometry as g
from stages.common import layout
from stages.common.robots.facility import Facility, load_facility, presented_share
from stages.common.target import Target
from stages.common.workspace_target import install, planned_target
from stages.plan import calibration_choice, covering
from stages.plan.config import PlanConfig
from stages.plan.facility_plan import (
    camera_fixture,
    dataset_redraws,
    light_box_centres,
    planned_facility,
    reconfigure_on,
)
from stages.plan.poses import (
    DatasetRange,
    PlanningError,
    calibration_pose,
    dataset_configuration,
    dataset_pose,
    dataset_range,
    facing_boxes,
    light_boxes,
    mount_away_from,
)
from stages.plan.reconfigure import Reconfiguration, reconfigure
from stages.plan.trajectory import SEQUENCE_COLUMNS, sequence_rows

__all__ = ["PlanningError", "dataset_count", "plan_sample", "planned_samples", "resolve", "run"]


def dataset_count(config: Config) -> int:
    """Dataset samples planned: ``plan.n_dataset``, or every sequence's frames."""
    if config.plan.mode == "trajectory":
        return config.trajectory.frames * len(config.trajectory.presets)
    return config.plan.n_dataset


def planned_samples(config: Config) -> list[tuple[str, int, str]]:
    """(session, index, sample_id) of every planned sample, in capture order."""
    ids = [("calibration", i, sample_ids.make("calibration", i)) for i in range(config.plan.n_calibration)]
    ids += [("dataset", i, sample_ids.make("dataset", i)) for i in range(dataset_count(config))]
    return ids


def skipped_in_chain(config: Config) -> bool:
    """A replayed session brings its own samples: ``speedplus run`` goes on without a plan."""
    return config.acquire.backend == "replay"


def resolve(config: Config, workspace: Workspace | None = None) -> Resolved:
    """Reads the configuration only; the [trajectory] section counts when the plan is made of
    sequences. Writes ``plan`` (and ``W/trajectories.json``, ``W/target/``)."""
    # on a facility, whether calibrate will fit its arms decides how the calibration poses are drawn
    fitting = tuple(f"calibrate.{key}" for key in ("arm_kinematics", "min_arm_redundancy", "joint_compliance",
                                                   "fixture_anisotropy")) if config.facility.path else ()
    sections = ("plan", "camera", "testbed", "facility.path", *fitting) + (
        ("trajectory",) if config.plan.mode == "trajectory" else ())
    extra = {"facility": facility_digest(Path(config.facility.path))} if config.facility.path else {}
    return Resolved((), sections, extra, ("plan",))


def trajectory_rows(config: Config, target: Target) -> tuple[list[dict], TrajectoriesRecord]:
    """Every sequence's rows, in capture order, and their record; nothing is written before
    all of them are placed (a refused sequence leaves the workspace as it was)."""
    rows, records = [], []
    for index, preset in enumerate(config.trajectory.presets):
        sequence, record = sequence_rows(config, target, index, preset, index * config.trajectory.frames)
        rows += sequence
        records.append(record)
    return rows, TrajectoriesRecord(tuple(records))


def plan_sample(config: Config, session: str, index: int, sample_id: str, target: Target | None = None,
                max_redraws: int | None = None, candidate: int = 0, spread_rail: bool = False) -> dict:
    """One row of the plan manifest (of ``target``, default the configured one).
    Unreachable relative poses are redrawn and counted, up to ``max_redraws`` (default
    ``plan.max_redraws``) times. ``candidate``: another draw of the same sample, from its
    own stream, and ``spread_rail`` its rail spread over the arm's reach
    (``calibration_choice`` keeps the best of several)."""
    plan, testbed, camera = config.plan, config.testbed, config.camera
    target = planned_target(config) if target is None else target
    facility = planned_facility(config)
    rng = np.random.default_rng([plan.seed, SESSION_CODES[session], index, *([candidate] if candidate else [])])
    if session == "calibration":
        view, light = target.view_names[0], "ambient"
    else:
        view, light = dataset_configuration(index, plan, target.view_names)
    # a facility folder may not show every view (one arm round a static target): its poses are
    # uniform over what it presents, each view as it falls (robots.facility.presented_share)
    wanted = view if facility is None else None
    chosen = dataset_range(plan, target, testbed, room=facility is None) if session == "dataset" else None
    limits: Counter[str] = Counter()

    def draw() -> tuple[np.ndarray, str, Reconfiguration | None]:
        if session == "calibration":
            cam_from_target = calibration_pose(rng, plan, testbed, camera, target)
            mount = plan.calibration_mounts[index % len(plan.calibration_mounts)]
        else:
            cam_from_target = dataset_pose(rng, plan, target, camera, wanted, chosen)
            mount = mount_away_from(cam_from_target)
        if facility is None:
            return cam_from_target, mount, reconfigure(cam_from_target, mount, plan, testbed, target,
                                                       require_far_side=session == "dataset")
        if isinstance(facility.holder("target"), StaticSpec):
            mount = plan.calibration_mounts[0]  # mounted once on its stand
        return cam_from_target, mount, reconfigure_on(facility, cam_from_target, mount, target, plan.seed, rng,
                                                      plan.joint_limit_margin_rad, limits, spread_rail=spread_rail)

    covered, discarded = None, 0
    if session == "calibration" and facility is None and not candidate:
        covered, discarded = covering.cover(config, index, target, rng, lambda j: plan_sample(
            config, "dataset", j, sample_ids.make("dataset", j), target))
    if covered is not None:
        (cam_from_target, mount, commands), redraws = covered, discarded
    else:
        cam_from_target, mount, commands, redraws = _drawn(draw, plan.max_redraws if max_redraws is None else
                                                           max_redraws, lambda draws: _unreachable(
                                                               sample_id, draws, testbed, target, chosen, facility,
                                                               limits))
        redraws += discarded  # the covering draws this sample's stream made first
    if session == "dataset" and facility is not None:
        camera_in_target = g.invert(cam_from_target)[:3, 3]
        view = target.view_of(camera_in_target, target.mockup_scale)
    fixture = layout.camee_from_cam(testbed) if facility is None else camera_fixture(facility)
    world_from_cam = commands.world_from_camee @ fixture
    world_from_target = world_from_cam @ cam_from_target
    centre = g.apply(world_from_target, (target.centre_m * target.mockup_scale)[None])[0]
    if facility is None:
        boxes = light_boxes(rng, plan, light, facing_boxes(testbed, centre, world_from_cam[:3, 3]))
    else:
        boxes = facility_light_boxes(rng, plan, light, light_box_centres(facility), centre, world_from_cam[:3, 3])
    return {
        "sample_id": sample_id,
        "session": session,
        **g.pose_columns("cam_from_target", cam_from_target),
        "view": view,
        "light": light,
        "light_boxes": boxes,
        "mount": mount,
        "rail_m": commands.rail_m,
        "camera_joints_rad": _listed(commands.camera_joints_rad),
        "target_joints_rad": _listed(commands.target_joints_rad),
        **g.pose_columns("world_from_camee", commands.world_from_camee),
        **g.pose_columns("world_from_targetee", commands.world_from_targetee),
        "reachable": True,
        "redraws": redraws,
        **dict.fromkeys(SEQUENCE_COLUMNS),
    }


def _drawn(draw: Callable[[], tuple[np.ndarray, str, Reconfiguration | None]], cap: int,
           refusal: Callable[[int], PlanningError]) -> tuple[np.ndarray, str, Reconfiguration, int]:
    """The first reachable of ``draw()``'s relative poses, redrawn up to ``cap`` times:
    (``cam_from_target``, mount, commands, redraws); ``refusal(draws)`` is raised past it."""
    redraws, (cam_from_target, mount, commands) = 0, draw()
    while commands is None:
        if redraws == cap:
            raise refusal(redraws + 1)
        redraws += 1
        cam_from_target, mount, commands = draw()
    return cam_from_target, mount, commands, redraws


def _unreachable(sample_id: str, draws: int, testbed: TestbedConfig, target: Target, chosen: DatasetRange | None,
                 facility: Facility | None, limits: Counter[str]) -> PlanningError:
    """The error of a sample no draw could place: what to check, and what stopped it."""
    hint = ""
    if facility is not None:
        total = sum(limits.values()) or 1
        hint = f"; on {facility.directory / 'facility.toml'}: " + "; ".join(
            f"{why} ({count / total:.0%})" for why, count in limits.most_common())
    if chosen is not None:
        room = testbed.room_m if facility is None else facility.spec.room_m
        hint += (f"; the {chosen.describe(target)}, in a {' x '.join(f'{v:g}' for v in room)} m "
                 "room (plan.dataset_range_m sets it in metres, plan.dataset_range_diameters narrows it)")
    where = ("the facility's robots and room, plan.calibration_distance_m and plan.dataset_range_m"
             if facility is not None else "testbed.target_presentation_m, testbed.rail_* and plan.sight_*")
    return PlanningError(f"sample {sample_id}: no reachable robot configuration in {draws} draws; check {where} "
                         f"(or raise plan.max_redraws){hint}")


def facility_rows(config: Config, calibration_poses: int | None = None) -> list[tuple[str, str]]:
    """``speedplus facility``'s rows of the plan: how well the calibration poses the plan
    draws on ``config``'s facility (``plan.n_calibration`` of them, or ``calibration_poses``;
    chosen or drawn as ``run`` makes them) determine its robots, before anything is captured."""
    facility = load_facility(Path(config.facility.path))
    target = planned_target(config)
    # the calibration session alone: the dataset's lights are not its to check
    count = config.plan.n_calibration if calibration_poses is None else calibration_poses
    config = config.replace(plan=dataclasses.replace(config.plan, n_dataset=0, n_calibration=count))
    fitted, why = calibration_choice.arms_fitted(config, facility, target)
    try:
        rows = (_choose(config, facility, target) if fitted else
                [plan_sample(config, "calibration", i, sample_id, target) for i, sample_id in
                 enumerate(_calibration_ids(config))])
    except PlanningError as error:  # the rest of the facility's table is still worth showing
        return [("calibration poses", f"none planned: {error}")]
    said = calibration_choice.describe(facility, rows, target)
    if said is None:
        return []
    return [("calibration poses", said + ("" if fitted else f"; drawn, not chosen: calibrate will leave the arms at "
                                                             f"their URDFs ({why})"))]


def status_note(config: Config, workspace: Workspace) -> str:
    """The share of the dataset poses drawn that the facility presented (``status``)."""
    rows = read_manifest(workspace, "plan").select(["session", "redraws", "view", "sequence_id"]).to_pylist()
    name = read_facility_spec(Path(config.facility.path)).name if config.facility.path else "TRON"
    return presented_share(rows, name)


def _listed(joints: np.ndarray | None) -> list[float] | None:
    """A robot's commanded joints; None: a static mount holds that body."""
    return None if joints is None else [float(v) for v in joints]


def facility_light_boxes(rng: np.random.Generator, plan: PlanConfig, light: str, centres: np.ndarray,
                         model_position: np.ndarray, camera_position: np.ndarray) -> list[int]:
    """Active light boxes of a facility folder for ``lightbox``: a uniform subset of the
    configured size (at most the boxes it has) of those on the camera's side of the model
    (of all, when fewer face it); none otherwise."""
    if light != "lightbox":
        return []
    facing = [i for i, c in enumerate(centres) if np.dot(c - model_position, camera_position - model_position) > 0]
    low, high = plan.light_boxes_per_sample
    count = min(int(rng.integers(low, high + 1)), len(centres))
    pool = facing if len(facing) >= count else list(range(len(centres)))
    return sorted(int(i) for i in rng.choice(pool, size=count, replace=False))


def _dataset_redraws(config: Config, facility: Facility | None, target: Target,
                     todo: list[tuple[str, int, str]]) -> int:
    """How many redraws each dataset pose left to plan may take (``dataset_redraws``: on a
    facility with a static mount, as many as the share it presents needs), said when raised."""
    remaining = sum(1 for session, _, _ in todo if session == "dataset")
    if facility is None or config.plan.mode == "trajectory" or not remaining:
        return config.plan.max_redraws
    chosen, scale = dataset_range(config.plan, target, config.testbed, room=False), target.mockup_scale
    redraws, said = dataset_redraws(config, facility, (chosen.low_m * scale, chosen.high_m * scale), remaining)
    if said:
        print(f"plan: {said}")
    return redraws


def _chosen_calibration(config: Config, facility: Facility | None, target: Target,
                        todo: list[tuple[str, int, str]]) -> dict[str, dict]:
    """The calibration rows of a facility folder's plan, chosen for what they determine of
    its robots (``calibration_choice``), by sample id; none on TRON (its closed-form grid),
    where calibrate will not fit the arms (``arms_fitted``: they are drawn one by one, as
    the dataset's are), or when no calibration sample is left to plan."""
    if facility is None or config.plan.mode == "trajectory" or not any(s == "calibration" for s, _, _ in todo):
        return {}
    fitted, why = calibration_choice.arms_fitted(config, facility, target)
    if not fitted:
        print(f"plan: calibration poses drawn, not chosen: calibrate will leave the arms at their URDFs ({why})")
        return {}
    return dict(zip(_calibration_ids(config), _choose(config, facility, target), strict=True))


def _calibration_ids(config: Config) -> list[str]:
    return [sample_ids.make("calibration", i) for i in range(config.plan.n_calibration)]


def _choose(config: Config, facility: Facility, target: Target) -> list[dict]:
    ids = _calibration_ids(config)
    return calibration_choice.choose_calibration(
        facility, target, len(ids),
        lambda i, k: plan_sample(config, "calibration", i, ids[i], target, config.plan.max_redraws, candidate=k,
                                 spread_rail=True))


def run(config: Config, workspace: Workspace) -> pa.Table:
    """Plan every sample missing from ``W/manifests/plan`` for the configured target, and
    copy the target into ``W/target`` for the later stages; returns the whole plan."""
    target = planned_target(config)
    done = read_keys(workspace, "plan")
    todo = [item for item in planned_samples(config) if item[2] not in done]
    sequences: dict[str, dict] = {}
    if config.plan.mode == "trajectory":
        rows, record = trajectory_rows(config, target)
        sequences = {row["sample_id"]: row for row in rows}
    facility = planned_facility(config)  # checked before anything is written
    if config.plan.n_dataset or config.plan.mode == "trajectory":  # sequences: the presets scale with it
        chosen = dataset_range(config.plan, target, config.testbed, room=facility is None)
        print(f"plan: {chosen.describe(target)}")
    redraws = {"calibration": config.plan.max_redraws, "dataset": _dataset_redraws(config, facility, target, todo)}
    chosen = _chosen_calibration(config, facility, target, todo)
    with open_sink(workspace, "plan", config.run.part_rows) as sink:
        for session, index, sample_id in track(todo, len(todo), "plan"):
            sink.add(sequences[sample_id] if sample_id in sequences else chosen[sample_id] if sample_id in chosen
                     else plan_sample(config, session, index, sample_id, target, redraws[session]))
    if config.plan.mode == "trajectory":
        write_trajectories(workspace, record)
    else:
        workspace.trajectories_path.unlink(missing_ok=True)
    install(config, workspace)
    table = read_manifest(workspace, "plan")
    if facility is None and config.plan.mode == "poses" and config.plan.calibration_cover:
        held, count = covering.count_covering(table.to_pylist())
        print(f"plan: {held} of {count} calibration poses hold the target arm at a dataset pose's configuration "
              f"(plan.calibration_cover = {config.plan.calibration_cover:g})")
    if facility is not None:
        print(f"plan: {presented_share(table.to_pylist(), facility.spec.name)}")
        observed = calibration_choice.describe(facility, table.to_pylist(), target, brief=True)
        if observed is not None:
            print(f"plan: {observed}")
    return table
