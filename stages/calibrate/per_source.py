"""One source's calibration as named steps (docs/architecture.md section 6): gather its
samples (``SourceSamples``), solve robustly and drop its outliers, cross-validate, fit the
arms where they are calibrated, and measure Table 1 (``SourceFit``); then the fused column
of Table 1 and the rejection sigma from both sources' fits."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from core import progress
from core.config import Config
from manifests import Workspace
from manifests.sidecars import (
    OFFSET_KEYS,
    SOURCES,
    ArmKinematics,
    Baseline,
    Folds,
    FusedColumn,
    Metrics,
    MetricSet,
    OffsetUncertainty,
    SigmaRecord,
    SourceCalibration,
)
from manifests.sidecars.arm_fit import ResidualNoise
from stages.calibrate import observations as obs
from stages.calibrate import screening
from stages.calibrate.arm_models import ArmsModel, Fitted, Readings, arms_model, facility_decision
from stages.calibrate.fitting import (
    CrossValidation,
    _subset,
    cross_validate,
    metrics,
    opencv_shah_metrics,
    pnp_variance,
    pose_covariances,
    robust_solve,
)
from stages.calibrate.offset_uncertainty import offsets_covariance, uncertainty
from stages.calibrate.robots import arm_decision, compliance_decision, compliance_record
from stages.common import arms, rwhe
from stages.common import geometry as g
from stages.common.fusion import Sigma, fuse, sigma_between, without_reference_noise
from stages.common.json_arrays import record
from stages.common.sources import measured_b, up_targetee
from stages.common.workspace_target import workspace_target


@dataclass(frozen=True)
class SourceSamples:
    """The captures a source measured, with what its calibration will take into account:
    PnP poses ``a`` and its ``b`` (N, 4, 4), fixtures, the up direction in the target flange
    (N, 3) where the fixtures' compliance is fitted, the arms' readings where they are."""

    used: list[obs.Observation]
    a: np.ndarray
    b: np.ndarray
    fixtures: list[str]
    up: np.ndarray | None
    readings: Readings | None
    arms: ArmsModel | None  # the arms' model, where they are fitted
    kinematic: bool  # the arms' kinematics are fitted
    compliance_note: str
    arm_note: str

    def inliers(self, keep: np.ndarray) -> SourceSamples:
        """The same samples less the solve's outliers (``keep`` (N,) bool)."""
        return SourceSamples(
            [o for o, k in zip(self.used, keep, strict=True) if k], self.a[keep], self.b[keep],
            [f for f, k in zip(self.fixtures, keep, strict=True) if k], _subset(self.up, keep),
            None if self.readings is None else self.readings.subset(keep), self.arms, self.kinematic,
            self.compliance_note, self.arm_note)


@dataclass(frozen=True)
class SourceFit:
    """A source's calibration and its estimates of ``cam_from_target`` per sample_id, in
    sample and cross-validated (each fold's from the others; the samples of determined
    folds only)."""

    calibration: SourceCalibration
    in_sample: dict[str, np.ndarray]
    cross_validated: dict[str, np.ndarray]


def gather(config: Config, workspace: Workspace, source: str, observations: list[obs.Observation],
           by_id: dict[str, dict[str, Any]]) -> SourceSamples:
    """The source's samples: every posed capture it measured; for the robots, the up
    direction and the compliance and arm decisions."""
    used = [o for o in observations if o.cam_from_target is not None
            and measured_b(by_id[o.sample_id], source) is not None]
    a = np.stack([o.cam_from_target for o in used]) if used else np.zeros((0, 4, 4))
    b = np.stack([measured_b(by_id[o.sample_id], source) for o in used]) if used else np.zeros((0, 4, 4))
    fixtures = [by_id[o.sample_id]["fixture"] for o in used]
    try:
        rwhe.check_diversity(b, fixtures, config.calibrate.min_samples, config.calibrate.min_rotation_spread_rad,
                             f"{source} calibration")
    except rwhe.DegenerateError as error:
        if source != "vicon":
            raise
        raise rwhe.DegenerateError(f"{error}; {markers_seen(observations, by_id)}") from None
    if source != "kuka":
        note = "motion capture tracks the model itself"
        return SourceSamples(used, a, b, fixtures, None, None, None, False, note, note)
    up = np.stack([up_targetee(by_id[o.sample_id], config.calibrate.world_up) for o in used])
    compliant, compliance_note = compliance_decision(config, up, fixtures)
    model = arms_model(config, arms.Payload.of(workspace_target(config, workspace)))
    readings = model.readings([by_id[o.sample_id] for o in used])
    kinematic, arm_note = arm_decision(config, readings)
    if kinematic:
        kinematic, arm_note = facility_decision(config, model, len(used), fixtures, compliant) or (kinematic, arm_note)
    return SourceSamples(used, a, b, fixtures, up if compliant else None, readings, model, kinematic,
                         compliance_note, arm_note)


def markers_seen(observations: list[obs.Observation], by_id: dict[str, dict[str, Any]], most: int = 12) -> str:
    """Which of its markers motion capture saw on each posed calibration capture it lost (a
    rigid body needs three): what a refusal for want of motion capture must say."""
    lost = [o.sample_id for o in observations if o.cam_from_target is not None
            and measured_b(by_id[o.sample_id], "vicon") is None]
    if not lost:
        return "motion capture measured every posed capture"

    more = f" and {len(lost) - most} more" if len(lost) > most else ""
    return (f"motion capture lost {len(lost)} posed capture(s), markers seen (a rigid body needs 3): "
            + "; ".join(f"{s} {markers_of(by_id[s], needs=False)}" for s in lost[:most]) + more
            + "; place the target's markers where the facility's cameras see them over the planned poses "
            "(target.toml [mockup] markers)")


def markers_of(capture: dict[str, Any], needs: bool = True) -> str:
    """The markers motion capture saw of each rigid body on one capture (``captures`` row)."""
    target, camera = capture.get("vicon_targetrb_markers"), capture.get("vicon_camrb_markers")
    seen = f"target body {'-' if target is None else target}, camera body {'-' if camera is None else camera}"
    return f"markers seen: {seen}; a rigid body needs 3" if needs else seen


def fit(config: Config, source: str, samples: SourceSamples, intrinsics: obs.EstimatedCamera,
        truth: dict[str, np.ndarray] | None) -> tuple[SourceFit, tuple[str, ...]]:
    """The source's calibration from its samples, and the outliers its robust solve dropped."""
    progress.note(f"calibrate {source}: robust solve on the {len(samples.used)} captures it measured with the "
                  "pattern found")
    solution, keep = robust_solve(config, samples.a, samples.b, samples.fixtures, samples.used, intrinsics,
                                  samples.up)
    screening.check_inliers(source, int(keep.sum()), len(keep))
    outliers = tuple(o.sample_id for o, k in zip(samples.used, keep, strict=True) if not k)
    s = samples.inliers(keep)
    b, up, fitted, before = s.b, s.up, None, None
    if s.kinematic:
        progress.note(f"calibrate {source}: the arms' fit on {len(s.used)} of those {len(samples.used)}"
                      + (f", less the outlier(s) {', '.join(outliers)}" if outliers else ""))
        fitted = s.arms.fit(s.a, s.readings, s.fixtures, solution, s.up is not None,
                            pose_covariances(config, s.used))
        # the folds judge the model the calibration reports: what its tests held is held there
        cross = cross_validate(config, s.a, s.b, s.fixtures, s.used, intrinsics, s.up, (s.arms, s.readings),
                               f"calibrate {source}", fitted.fit.verdicts())
        solution = fitted.offsets
        _note_residual_noise(source, fitted.fit.residual_noise())
        b, up_arms = fitted.corrected_b(s.readings)
        up = None if up is None else up_arms
        before = fitted.up_before(s.readings)
    else:
        cross = cross_validate(config, s.a, s.b, s.fixtures, s.used, intrinsics, s.up, label=f"calibrate {source}")
    predicted = solution.predict(b, s.fixtures, up, before)
    offsets = _offset_uncertainty(source, s, solution, b, up, fitted)
    in_sample = metrics(predicted, s.a, s.used, intrinsics)
    if not cross.judged:
        progress.note(f"calibrate {source}: {cross.folds - len(cross.undetermined_folds)} of {cross.folds} folds "
                      "determine the offsets, too few to judge the data: the in-sample fit alone is judged")
    cross_metrics = _determined_metrics(cross, s.a, s.used, intrinsics)
    screening.check_result(source, in_sample, cross_metrics if cross.judged else None, intrinsics, config.calibrate,
                           cross.record())
    calibration = SourceCalibration(
        source=source, cam_from_offset=record(solution.z),
        target_from_offset_by_fixture={f: record(x) for f, x in solution.x.items()},
        fixture_compliance=compliance_record(solution, up, s.fixtures, s.compliance_note,
                                             fitted.fit.play_why if fitted is not None else ""),
        arm_kinematics=fitted.kinematics(s.arm_note) if fitted is not None else ArmKinematics(False, s.arm_note),
        sigma=without_reference_noise(sigma_between(predicted, s.a), *pnp_variance(s.used)).to_record(),
        samples=len(s.used), outliers=outliers,
        metrics=_column(in_sample, cross_metrics, cross.record(), _truth_metrics(predicted, s.used, intrinsics, truth)),
        # OpenCV's Shah on the same detections and intrinsics, for comparison
        opencv_shah_in_sample=(Baseline.of(opencv_shah_metrics(s.a, s.b, s.fixtures, s.used, intrinsics))
                               if len(solution.x) == 1 else None),
        offset_uncertainty=offsets)
    ids = [o.sample_id for o in s.used]
    determined = {i: p for i, p, d in zip(ids, cross.predicted, cross.determined, strict=True) if d}
    return SourceFit(calibration, dict(zip(ids, predicted, strict=True)), determined), outliers


def _note_residual_noise(source: str, noise: ResidualNoise) -> None:
    """Say what the arms' model leaves unexplained in a calibration pose (calibration.json:
    ``arm_kinematics.chains.residual_noise``)."""
    sizes = f"{np.degrees(noise.rotation_sigma_rad):.4f} deg and {noise.translation_sigma_m * 1000:.3f} mm"
    if noise.pnp_scale is None:
        progress.note(f"calibrate {source}: the calibration poses differ from the arms' prediction by {sizes} "
                      "(1-sigma per axis, the PnP poses' own error included: calibrate.pose_weights = groups)")
    else:
        progress.note(f"calibrate {source}: the arms' model leaves {sizes} a pose unexplained (1-sigma per axis); "
                      f"the PnP poses err {np.sqrt(noise.pnp_scale):.2f} times what their corners predict")


def _offset_uncertainty(source: str, s: SourceSamples, solution: rwhe.Solution, b: np.ndarray,
                        up: np.ndarray | None, fitted: Fitted | None) -> OffsetUncertainty:
    """The offsets' covariance (the arms' fit's block where the arms were fitted) and the
    directions it leaves weak, each said on the console."""
    names = sorted(solution.x)
    size = 6 + 6 * len(names)
    covariance = (fitted.offsets_covariance()[:size, :size] if fitted is not None
                  else offsets_covariance(s.a, b, s.fixtures, solution, up))
    z_name, x_name = OFFSET_KEYS[source]
    record = uncertainty(covariance, solution, z_name, x_name, s.b)
    for sentence in record.weak:
        progress.note(f"calibrate {source}: weakly determined: {sentence}")
    return record


def _column(in_sample: dict[str, list[float]], cross_validated: dict[str, list[float]] | None,
            folds: Folds, truth: dict[str, list[float]] | None) -> Metrics:
    """A column of Table 1 as calibration.json keeps it."""
    def typed(values: dict[str, list[float]] | None) -> MetricSet | None:
        return None if values is None else MetricSet.of(values)

    return Metrics(MetricSet.of(in_sample), typed(cross_validated), folds, typed(truth))


def _determined_metrics(cross: CrossValidation, a: np.ndarray, used: list[obs.Observation],
                        intrinsics: obs.EstimatedCamera) -> dict[str, list[float]] | None:
    """Table 1's cross-validated metrics over the determined folds' samples (None: no fold is)."""
    if not cross.determined.any():
        return None
    chosen = [o for o, d in zip(used, cross.determined, strict=True) if d]
    return metrics(cross.predicted[cross.determined], a[cross.determined], chosen, intrinsics)


def _truth_metrics(predicted: np.ndarray, used: list[obs.Observation], intrinsics: obs.EstimatedCamera,
                   truth: dict[str, np.ndarray] | None) -> dict[str, list[float]] | None:
    """Table 1 against the hidden truth (the virtual testbed's), else None."""
    if truth is None:
        return None
    true = np.stack([truth[o.sample_id] for o in used])
    true_pixels = [g.project(t, o.object_points, intrinsics.camera_matrix, intrinsics.dist)
                   for t, o in zip(true, used, strict=True)]
    return metrics(predicted, true, used, intrinsics, true_pixels)


def _fused(by_source: dict[str, np.ndarray], sigma: dict[str, Sigma]) -> np.ndarray:
    """The fused estimates (N, 4, 4) of the sources' (N, 4, 4) with their sigmas."""
    return np.stack([fuse(k, sigma["kuka"], v, sigma["vicon"])[0]
                     for k, v in zip(by_source["kuka"], by_source["vicon"], strict=True)])


def fused_column(observations: list[obs.Observation], fits: dict[str, SourceFit], intrinsics: obs.EstimatedCamera,
                 truth: dict[str, np.ndarray] | None) -> tuple[FusedColumn, SigmaRecord]:
    """Table 1's fused column on the samples both sources measured (each source's own column
    is over its own samples, as in the paper; fusion is judged against the single sources
    on the same samples), and the spread of motion capture against the robots (the
    rejection test's sigma)."""
    kuka, vicon = fits["kuka"], fits["vicon"]
    both = [o for o in observations if o.sample_id in kuka.in_sample and o.sample_id in vicon.in_sample]
    rejection = sigma_between(np.stack([vicon.in_sample[o.sample_id] for o in both]),
                              np.stack([kuka.in_sample[o.sample_id] for o in both])).to_record()
    sigma = {s: Sigma.from_record(fits[s].calibration.sigma) for s in SOURCES}

    # cross-validated: the samples where both sources' folds determined their offsets
    judged = [o for o in both if all(o.sample_id in fits[s].cross_validated for s in SOURCES)]
    found: dict[str, dict[str, Any]] = {name: {"cross_validated": None} for name in (*SOURCES, "fused")}
    for which, chosen in (("in_sample", both), ("cross_validated", judged)):
        if not chosen:
            continue
        by_source = {s: np.stack([getattr(fits[s], which)[o.sample_id] for o in chosen]) for s in SOURCES}
        a = np.stack([o.cam_from_target for o in chosen])
        for name, estimates in (*by_source.items(), ("fused", _fused(by_source, sigma))):
            found[name][which] = metrics(estimates, a, chosen, intrinsics)
            if which == "in_sample":
                found[name]["truth"] = _truth_metrics(estimates, chosen, intrinsics, truth)
    on_both = {name: _column(f["in_sample"], f["cross_validated"], Folds(len(judged)), f["truth"])
               for name, f in found.items()}
    return FusedColumn(len(both), on_both["fused"], {s: on_both[s] for s in SOURCES}), rejection
