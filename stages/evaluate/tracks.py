"""The tracking baseline of evaluate for a trajectory plan: per model, crop, sequence and
domain, the filter of ``stages/common/tracking.py`` fed the per-frame predictions in frame
order, scored against the labels like the frames themselves (the ``tracks`` manifest)."""

from __future__ import annotations

from itertools import groupby
from typing import Any

import numpy as np
from rich import box
from rich.table import Table

from core.config import Config
from manifests import Workspace, read_manifest, to_table
from manifests.schema import TRACKS
from manifests.sidecars import read_trajectories
from stages.common import geometry as g
from stages.common.orbits import Elements, rtn_from_eci, two_body
from stages.common.scores import score
from stages.common.tracking import Measurement, TrackingNoise, track


def noise(config: Config) -> TrackingNoise:
    e = config.evaluate
    return TrackingNoise(e.tracking_rotation_sigma_rad, e.tracking_lateral_sigma, e.tracking_depth_sigma,
                         e.tracking_angular_acceleration_sigma, e.tracking_roe_walk, e.tracking_gate_probability)


def _domain(prediction: dict[str, Any]) -> str:
    return "synthetic" if prediction["domain"] == "synthetic" else "testbed"


def _measurement(prediction: dict[str, Any], frame: dict[str, Any], chief: Elements) -> Measurement:
    position, velocity = two_body(chief, [frame["time_s"]])
    latitude = chief.mean_latitude_rad(frame["time_s"])
    measured = None
    if prediction["pose_found"] and prediction["q_pred"] is not None:
        measured = g.transform_from_qt(prediction["q_pred"], prediction["t_pred"])
    return Measurement(frame["time_s"], measured, g.quat_to_matrix(frame["eci_from_cam_q"]),
                       rtn_from_eci(position, velocity)[0], float(latitude))


def tracks(config: Config, workspace: Workspace, predictions: list[dict[str, Any]]) -> Any:
    """The ``tracks`` table of every (model, crop, domain, sequence) among ``predictions``."""
    record = read_trajectories(workspace)
    frames = {r["sample_id"]: r for r in read_manifest(workspace, "plan").to_pylist() if r["sequence_id"] is not None}
    labels = {r["sample_id"]: r for r in read_manifest(workspace, "labels").to_pylist()}
    rows = []

    def key(p: dict[str, Any]) -> tuple:
        frame = frames[p["sample_id"]]
        return p["model"], p["crop"], _domain(p), frame["sequence_id"], frame["frame"]

    chosen = sorted((p for p in predictions if p["sample_id"] in frames), key=key)
    for (model, crop, domain, sequence_id), group in groupby(chosen, key=lambda p: key(p)[:4]):
        group = list(group)
        sequence = record.sequence(sequence_id)
        chief = Elements(**sequence.chief)
        measurements = [_measurement(p, frames[p["sample_id"]], chief) for p in group]
        tracked = track(measurements, chief, np.asarray(sequence.centre_of_mass_m), noise(config))
        for prediction, estimate, measurement in zip(group, tracked, measurements, strict=True):
            frame, label = frames[prediction["sample_id"]], labels[prediction["sample_id"]]
            known = bool(np.all(np.isfinite(estimate.cam_from_target)))
            q_track, t_track = g.transform_to_qt(estimate.cam_from_target) if known else (None, None)
            scored = score(q_track, t_track, label["q_vbs2tango_true"], label["r_Vo2To_vbs_true"]) if known else \
                {"err_q_rad": np.pi, "err_t_norm": 1.0, "score_speed": np.pi + 1.0}
            rows.append({
                "track_id": f"{model}:{crop}:{domain}:{prediction['sample_id']}", "model": model, "crop": crop,
                "domain": domain, "sequence_id": sequence_id, "frame": frame["frame"], "time_s": frame["time_s"],
                "sample_id": prediction["sample_id"], "measured": measurement.cam_from_target is not None,
                "rotation_used": estimate.rotation_used,
                "position_used": estimate.position_used, "q_track": q_track, "t_track": t_track,
                "err_q_rad": float(scored["err_q_rad"]), "err_t_norm": float(scored["err_t_norm"]),
                "score_speed": float(scored["score_speed"]), "frame_score_speed": prediction["score_speed"]})
    return to_table(rows, TRACKS)


def tracking_tables(table: Any) -> list[Table]:
    """Per model: for each crop, sequence and domain the mean SPEED score per frame against
    tracked, and the frames the attitude filter took; 80 columns."""
    rows = sorted(table.to_pylist(), key=lambda r: (r["model"], r["crop"], r["sequence_id"], r["domain"], r["frame"]))
    out = []
    for model, of_model in groupby(rows, key=lambda r: r["model"]):
        shown = Table(title=f"Tracking: {model}, mean SPEED score", box=box.SIMPLE_HEAD, title_justify="left",
                      caption="frame: per frame; tracked: the filter's; used: frames its attitude filter took",
                      caption_justify="left")
        for column in ("crop", "sequence", "domain", "n", "frame", "tracked", "used"):
            shown.add_column(column, no_wrap=True, justify="right" if column in ("n", "frame", "tracked") else "left")
        for (crop, sequence_id, domain), group in groupby(of_model, key=lambda r: (r["crop"], r["sequence_id"],
                                                                                    r["domain"])):
            group = list(group)
            shown.add_row(crop, sequence_id, domain, str(len(group)),
                          f"{np.mean([r['frame_score_speed'] for r in group]):.4f}",
                          f"{np.mean([r['score_speed'] for r in group]):.4f}",
                          f"{sum(r['rotation_used'] for r in group)}/{len(group)}")
        out.append(shown)
    return out
