"""The render stage's ``run`` and ``resolve`` (what the stage does: the package's docstring).

``render.set = twin`` writes the ``renders`` manifest and ``W/renders/twins/``;
``render.set = train`` writes the ``train`` manifest and ``W/renders/train/``. Each image
depends only on its job (pose, light, seed), so the local and Ray engines give the same
pixels and an interrupted run resumes with the missing ``sample_id``s.
"""

from __future__ import annotations

from dataclasses import replace

import pyarrow as pa

from core.config import Config
from core.config.params import keys_for
from core.engines import store, threads_per_worker
from core.progress import console, track
from core.stage_io import Resolved
from manifests import Workspace, list_parts, open_sink, read_keys, read_manifest, read_marker
from manifests.files import write_json_atomic
from stages.common.cameras import train_camera
from stages.common.dispatch import map_config
from stages.common.json_arrays import calibrated_camera
from stages.common.tone import Response
from stages.common.workspace_target import workspace_target
from stages.render.config import RenderConfig
from stages.render.jobs import SET_DIRECTORIES, train_jobs, twin_jobs
from stages.render.worker import open_worker


def output_name(config: Config) -> str:
    return "renders" if config.render.set == "twin" else "train"


def resolve(config: Config, workspace: Workspace | None = None) -> Resolved:
    """Each image set depends on the render keys that shape it (``applies`` of each field:
    resizing the training set leaves the twins done), the camera's sensor and tone, and on
    its inputs: the twins read the labels, the captures (the camera's place), the calibration
    and the plan (each sample's light, a sequence's Earth)."""
    keys = tuple(f"render.{key}" for key in keys_for(RenderConfig, config.render.set))
    if config.render.set == "train":
        return Resolved((), ("camera", *keys), {}, (output_name(config),))
    inputs = ("labels", "captures", "calibration_samples")
    if config.acquire.backend == "virtual":
        inputs += ("plan",)  # the light set-up of each sample
    lights = ("testbed.light_box_centres_m", "testbed.sun_lamp_position_m")  # where the twin's light comes from
    return Resolved(inputs, (*lights, "camera.sensor", "camera.gamma", "plan.mode", *keys), {},
                    (output_name(config),))


def status_views(config: Config, workspace: Workspace) -> list[tuple[str, Config]]:
    """The twins, and the training set where the workspace has one (``render --set train``
    makes it, under the configuration's ``render.train_*``)."""
    views = [("render", config.replace(render=replace(config.render, set="twin")))]
    if read_marker(workspace, "train") is not None or list_parts(workspace, "train"):
        views.append(("render train", config.replace(render=replace(config.render, set="train"))))
    return views


def response(config: Config) -> Response:
    """The configured camera's sensor and tone, which every rendered image follows."""
    return Response(config.camera.sensor, config.camera.gamma)


def run(config: Config, workspace: Workspace) -> pa.Table:
    """Render every job missing from the manifest; returns the manifest."""
    name = output_name(config)
    target = workspace_target(config, workspace)
    rejected: list[dict[str, str]] = []
    if config.render.set == "twin":
        camera = calibrated_camera(workspace)
        jobs, rejected = twin_jobs(config, workspace)
    else:
        camera = train_camera(config)
        jobs = train_jobs(config, target)
    done = read_keys(workspace, name)
    todo = [job for job in jobs if job.sample_id not in done]
    run_config = config.run
    threads = threads_per_worker(run_config.workers)
    spp = config.render.spp if config.render.set == "twin" else config.render.train_spp
    args = (camera, target, spp, config.render.max_depth, threads, config.render.ground_truth, response(config))
    produced = map_config(config, open_worker, args, "render", todo, renders=True, remote=workspace.remote)
    with open_sink(workspace, name, run_config.part_rows) as sink:
        for output in track(produced, len(todo), f"render {config.render.set} ({run_config.engine})"):
            row = store(workspace, output)
            if "rejected" in row:
                rejected.append({"sample_id": row["sample_id"], "reason": row["rejected"]})
            else:
                sink.add(row)
    rejected.sort(key=lambda entry: entry["sample_id"])
    write_json_atomic(workspace.root / "renders" / SET_DIRECTORIES[config.render.set] / "rejected.json", rejected)
    for entry in rejected:
        console.print(f"[yellow]render: {entry['sample_id']} not rendered: {entry['reason']}[/]")
    return read_manifest(workspace, name)
