"""The fuse stage's ``run`` and ``resolve`` (what the stage does: the package's docstring).

It reads the captures and ``W/calibration.json``, never the truth. The calibrated sigmas
were measured at the calibration distance and arm configurations; on the dataset
captures they grow with the lever of the line of sight, with the calibrated arms'
parameter uncertainty propagated to each capture's configuration, and by the session's
a posteriori variance factor: how much the two sources disagree on its own captures
beyond what those sigmas predict (``W/fusion.json``). On an axis where that disagreement
fails a 95% test of consistency, the better source there is kept alone (``axis_sources``):
fusing would let the worse pull the better, and the better is the one whose error each
source's own measurements at the captures predict the smaller (``session.better_source``).
Motion capture's sigma at each capture carries
its rigid-body fit's geometry there (``marker_geometry.py``); a session too short to
measure the factor widens the sigmas to the calibration's cross-validated errors
(``short_session.py``). The median difference of the two over the session is first
removed from the worse source (``session_offset``), so that only the
capture-to-capture errors are fused, with a factor measured on them (``applied_factor``).
The session-level measures are in ``session.py``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow as pa

from core.config import Config, TestbedConfig
from core.progress import track
from core.stage_io import Resolved
from manifests import Workspace, open_sink, read_keys, read_manifest
from manifests.sidecars import Calibration, FusionRecord, SourceCalibration, read_calibration, write_fusion
from manifests.workspace import FUSION_FILE
from speedplus.errors import InputError
from stages.common import arms
from stages.common import geometry as g
from stages.common.fusion import Sigma, VarianceFactor, at_position, fuse, rejection_reason, with_scale_error
from stages.common.json_arrays import matrix
from stages.common.robots import identification, lost_motion
from stages.common.robots.errors import Holders, configured_holders
from stages.common.rwhe import Solution
from stages.common.sources import measured_b, up_targetee
from stages.common.workspace_target import workspace_target
from stages.fuse.config import FuseConfig
from stages.fuse.kept_axes import SourceFactors
from stages.fuse.marker_geometry import FitVariance, MarkerGeometry, with_marker_geometry
from stages.fuse.session import (
    NO_OFFSET,
    SessionOffset,
    applied_factor,
    axis_sources,
    rejections,
    session_factor,
    session_fusion,
    session_offset,
)
from stages.fuse.short_session import widened_for_short_session

__all__ = ["Estimates", "SessionOffset", "applied_factor", "axis_sources", "fuse_capture", "rejections", "resolve",
           "run", "session_factor", "session_fusion", "session_offset", "widened_for_short_session",
           "with_marker_geometry"]


class SourceModel:
    """One source's calibrated offsets, fixture compliance and uncertainty."""

    def __init__(self, entry: SourceCalibration, calibration: Calibration, payload: arms.Payload,
                 scale_sigma: float = 0.0, holders: Holders | None = None, tron: bool = False) -> None:
        self.tron = tron  # TRON's own arms: the KR 16-2's lost motion applies
        kinematics = entry.arm_kinematics
        self.kinematics = kinematics
        #: the facility's robots, fitted from their URDFs (``kinematics.chains``)
        self.holders = holders if kinematics.chains is not None else None
        #: above it a joint rests on its loaded flank, as calibrate took it
        self.preload_nm = kinematics.chains.backlash_preload_nm if kinematics.chains is not None else np.inf
        if kinematics.chains is not None and (holders is None or holders.names != kinematics.chains.parameter_names):
            raise InputError("calibration.json: arm_kinematics.chains was fitted to other robots than the facility "
                             "folder's (its parameter names differ); rerun calibrate with --force (`speedplus "
                             "calibrate -w W --force`)")
        self.payload = payload
        #: the offsets, the fixtures' sag and play, as ``rwhe.Solution`` predicts with them
        self.offsets = Solution(
            matrix(entry.cam_from_offset),
            {fixture: matrix(pose) for fixture, pose in entry.target_from_offset_by_fixture.items()},
            {fixture: np.asarray(k, float) for fixture, k in entry.compliance_k_rad.items()},
            {fixture: np.asarray(d, float) for fixture, d in entry.compliance_anisotropy.items()},
            dict(entry.compliance_play_rad))
        self.sigma = Sigma.from_record(entry.sigma)
        self.metrics, self.samples = entry.metrics, entry.samples
        #: how much wider the arms' parameters are than their fit says (a short session's widening)
        self.parameter_scale = 1.0
        self.calibration_lever_sq = np.array(calibration.calibration_lever_sq_m2, float)
        self.calibration_distance_m = calibration.calibration_distance_m
        self.world_up = np.asarray(calibration.world_up, float)  # the up the compliance was fitted with
        self.scale_sigma = scale_sigma

    def check_fixture(self, row: dict[str, Any]) -> None:
        """Refuse a capture on a fixture the calibration never saw, naming it."""
        fixture = row["fixture"]
        if fixture not in self.offsets.x:
            raise InputError(f"captures: sample {row['sample_id']} uses fixture {fixture!r}, which the calibration "
                             f"did not see (calibrated: {', '.join(sorted(self.offsets.x))}); add calibration captures "
                             "with it")

    def estimate(self, b: np.ndarray, row: dict[str, Any]) -> np.ndarray:
        """``cam_from_target`` (4, 4) of a capture from this source's measurement ``b``."""
        self.check_fixture(row)
        fixture = row["fixture"]
        up, before = up_targetee(row, self.world_up), None
        if self.holders is not None:
            measured = identification.measured(self.holders, [row], self.payload, self.world_up, self.preload_nm)
            if measured is None:
                raise InputError(f"captures: sample {row['sample_id']} lacks the robots' encoder readings, which the "
                                 "calibration of the arms needs (calibrate.arm_kinematics)")
            size = self.holders.size
            arm_params = np.asarray(self.kinematics.chains.parameters)[:size]
            b_arms, up_arms = identification.corrected_b(self.holders, arm_params, measured, self.world_up)
            b, up = b_arms[0], up_arms[0]
            before = identification.up_before(self.holders, arm_params[None], measured, self.world_up)[0, 0]
        return self.offsets.predict(b[None], [fixture], None if up is None else up[None],
                                    None if before is None else before[None])[0]

    def sigma_at(self, pose: np.ndarray, sigma: Sigma | None = None) -> Sigma:
        """This source's sigma (or ``sigma``, measured at the calibration) grown to ``pose``:
        the line of sight's lever, and the distances' scale error beyond the calibration's."""
        grown = at_position(self.sigma if sigma is None else sigma, pose[:3, 3], self.calibration_lever_sq)
        return with_scale_error(grown, pose[:3, 3], self.calibration_distance_m, self.scale_sigma)

    def parameter_covariances(self, rows: list[dict[str, Any]], fuse: FuseConfig) -> list[ArmUncertainty | None]:
        """Each capture's pose uncertainty from the calibrated arms' parameters and the
        joints' lost motion the fit leaves out (``lost_motion.flank_variances``: where the
        flank is unknown, the fitted lost motion; where it was not fitted, on TRON's arms,
        ``fuse.lost_motion_rad``, the KR 16-2's rating, as a facility folder's URDF gives no
        gearbox data); None without calibrated arms. All captures at once."""
        for row in rows:  # before the arms' model meets a fixture it has no offset for
            self.check_fixture(row)
        if self.holders is None or not rows:
            return [None] * len(rows)
        measured = identification.measured(self.holders, rows, self.payload, self.world_up, self.preload_nm)
        if measured is None:
            raise InputError("captures: dataset captures lack the robots' encoder readings, which the calibration "
                             "of the arms needs (calibrate.arm_kinematics)")
        jacobians = identification.pose_jacobians(self.holders, self.kinematics.chains, measured, self.world_up)
        parameters = np.asarray(self.kinematics.covariance) * self.parameter_scale**2
        flanks = lost_motion.flank_variances(self.holders, measured, self.kinematics.chains,
                                             fuse.lost_motion_rad if self.tron else None, self.parameter_scale)
        shared, own = arms.pose_covariance_parts(jacobians, parameters, flanks,
                                                 identification.joint_columns(self.holders))
        return [ArmUncertainty(s + o, j[3:], parameters) for s, o, j in zip(shared, own, jacobians, strict=True)]


@dataclass(frozen=True)
class ArmUncertainty:
    """A capture's pose covariance from the calibrated arms, and how its position error
    depends on the arms' parameters, whose one error the session's captures share."""

    covariance: np.ndarray  # (6, 6): rotation (rad), then position (m)
    jacobian_t: np.ndarray  # (3, P) m per unit of each parameter
    parameters: np.ndarray  # (P, P) the parameters' covariance

    def with_session_mean_t_m2(self, mean_jacobian_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per camera axis (3,) m^2: the covariance of this capture's position error from
        the parameters with that error's mean over the captures whose mean Jacobian is
        ``mean_jacobian_t`` (3, P), and the mean's variance."""
        with_mean = np.einsum("ap,pq,aq->a", self.jacobian_t, self.parameters, mean_jacobian_t)
        return with_mean, np.einsum("ap,pq,aq->a", mean_jacobian_t, self.parameters, mean_jacobian_t)


def load_models(workspace: Workspace, testbed: TestbedConfig, payload: arms.Payload, vicon_scale_sigma: float,
                facility: str = "") -> tuple[SourceModel, SourceModel | None, Sigma | None]:
    """Both sources' calibrated models and the rejection sigma, from ``W/calibration.json``;
    ``facility``: the facility folder's path, whose robots calibrate fitted (empty: TRON's,
    placed by ``testbed``)."""
    calibration = read_calibration(workspace)
    holders = configured_holders(facility, testbed)[0]
    kuka = SourceModel(calibration.kuka, calibration, payload, holders=holders, tron=not facility)
    vicon = rejection = None
    if calibration.vicon is not None:
        vicon = SourceModel(calibration.vicon, calibration, payload, vicon_scale_sigma)
        rejection = Sigma.from_record(calibration.rejection)
    return kuka, vicon, rejection


@dataclass(frozen=True)
class Estimates:
    """A dataset capture's pose (4, 4) from each source; ``vicon`` None when not measured."""

    row: dict[str, Any]
    kuka: np.ndarray
    vicon: np.ndarray | None
    arm: ArmUncertainty | None  # from the calibrated arms' parameters and joints
    fit: FitVariance | None = None  # motion capture's target-body fit here (None: not recorded)

    @property
    def tracked(self) -> bool:
        """Motion capture gave a finite pose of this capture, from markers that determine it."""
        return (self.vicon is not None and bool(np.all(np.isfinite(self.vicon)))
                and (self.fit is None or bool(np.all(np.isfinite(self.fit.t_m2)))))

    def vicon_sigma(self, vicon: SourceModel, pose: np.ndarray, sigma: Sigma | None = None) -> Sigma:
        """Motion capture's sigma (or ``sigma``, measured at the calibration) at this capture:
        grown to ``pose`` (``SourceModel.sigma_at``), plus its target-body fit's here."""
        grown = vicon.sigma_at(pose, sigma)
        return grown if self.fit is None else self.fit.add_to(grown)

    def rejection(self, vicon: SourceModel | None, rejection: Sigma | None, factor: VarianceFactor,
                  k: float, offset: SessionOffset = NO_OFFSET) -> str | None:
        """Why motion capture is not fused at this capture, or None: untracked, or beyond
        ``k`` of the difference's sigma (the rejection sigma grown here, scaled by
        ``factor``) from the robots, both in the better source's offset."""
        if vicon is None:
            return "no motion capture in this session"
        if self.vicon is not None and not self.tracked:
            return "the markers its fit used cannot determine the pose (three in a line)"
        predicted = self.plus_parameters(self.vicon_sigma(vicon, self.kuka, rejection))
        vicon_pose = offset.motion_capture(self.vicon) if self.tracked else self.vicon
        return rejection_reason(offset.robots(self.kuka), vicon_pose, factor.scale(predicted), k)

    def plus_parameters(self, sigma: Sigma) -> Sigma:
        """``sigma`` with the robots' parameter uncertainty at this capture added."""
        if self.arm is None:
            return sigma
        covariance = self.arm.covariance
        return Sigma(np.sqrt(sigma.t_m**2 + np.diag(covariance)[3:]),
                     float(np.sqrt(sigma.r_rad**2 + np.trace(covariance[:3, :3]))), sigma.pointing_rad)


def estimate(row: dict[str, Any], kuka: SourceModel, vicon: SourceModel | None,
             arm: ArmUncertainty | None, geometry: MarkerGeometry | None = None) -> Estimates:
    vicon_pose = None
    if vicon is not None:
        b = measured_b(row, "vicon")
        vicon_pose = None if b is None else vicon.estimate(b, row)
    kuka_pose = kuka.estimate(measured_b(row, "kuka"), row)
    fit = None if geometry is None or vicon_pose is None else geometry.variance(row, kuka_pose)
    return Estimates(row, kuka_pose, vicon_pose, arm, fit)


def offset_variance(e: Estimates, factor: VarianceFactor, offset: SessionOffset,
                    vicon_weight: np.ndarray) -> np.ndarray:
    """(3,) m^2 that a label whose position is ``vicon_weight`` (3,) motion capture's adds
    to the inverse-variance fusion's variance when the session offset was removed.

    The removed offset's standard error reaches the label through the share of the source
    it was removed from. And where motion capture's offset was removed, the robots' error
    from their calibrated parameters is not averaged as fusion assumes: the median
    difference carried the session's mean of it, ``m``, into motion capture's positions,
    so the label's share of that error is ``(1 - w) c + w m`` (``c``: this capture's), not
    ``(1 - w) c``; the difference of the variances, ``w^2 var m + 2 w (1 - w) cov(c, m)``,
    is added (``m``'s Jacobian: ``SessionOffset.mean_jacobian_t``)."""
    if not offset.estimated:
        return np.zeros(3)
    from_vicon = np.array([source == "vicon" for source in offset.removed_from])
    shifted = np.where(from_vicon, vicon_weight, 1.0 - vicon_weight)
    extra = np.zeros(3)
    if e.arm is not None and offset.mean_jacobian_t is not None:
        with_mean, mean = e.arm.with_session_mean_t_m2(offset.mean_jacobian_t)
        w = vicon_weight
        extra = np.where(from_vicon, factor.t**2 * (w**2 * mean + 2 * w * (1 - w) * with_mean), 0.0)
    return (shifted * offset.sigma_m) ** 2 + extra


def fuse_capture(e: Estimates, kuka: SourceModel, vicon: SourceModel | None, rejection: Sigma | None,
                 factor: VarianceFactor, rejection_k: float, sources: tuple[str, ...] = ("fused",) * 3,
                 offset: SessionOffset = NO_OFFSET, by_source: SourceFactors | None = None) -> dict[str, Any]:
    """One ``poses`` row; ``sources``: per camera axis, fused or one source alone
    (``axis_sources``); ``offset``: removed before fusing (``session_offset``); ``by_source``:
    each source's own factor, which scales its sigma alone (``kept_axes``; None: ``factor``'s)."""
    by_source = by_source or SourceFactors.common(factor.t)
    calibrated_kuka = e.plus_parameters(kuka.sigma_at(e.kuka))
    # both in the offset of the better source: tested and fused on what
    # varies from capture to capture only, and a robots-only label in the session's offset
    kuka_pose = offset.robots(e.kuka)
    vicon_pose = offset.motion_capture(e.vicon) if e.tracked else e.vicon
    reason = e.rejection(vicon, rejection, factor, rejection_k, offset)
    # per axis, the share of the label that comes from motion capture
    vicon_weight = np.zeros(3)
    if reason is None:
        calibrated_vicon = e.vicon_sigma(vicon, e.vicon)
        scaled_kuka, scaled_vicon = factor.scale(calibrated_kuka), factor.scale(calibrated_vicon)
        fused, sigma = fuse(kuka_pose, scaled_kuka, vicon_pose, scaled_vicon)
        vicon_weight = scaled_kuka.t_m**2 / (scaled_kuka.t_m**2 + scaled_vicon.t_m**2)
    else:
        fused, sigma = kuka_pose.copy(), factor.scale(calibrated_kuka)
    t_m = sigma.t_m.copy()
    for axis, source in enumerate(sources):
        if source != "fused":  # motion capture alone where it passed the rejection test, else the robots
            mocap = source == "vicon" and reason is None
            pose, alone = (vicon_pose, calibrated_vicon) if mocap else (kuka_pose, calibrated_kuka)
            own = by_source.of("vicon" if mocap else "kuka")[axis]
            fused[axis, 3], t_m[axis] = pose[axis, 3], own * alone.t_m[axis]
            vicon_weight[axis] = float(mocap)
    t_m = np.sqrt(t_m**2 + offset_variance(e, factor, offset, vicon_weight))
    vicon_sigma = by_source.vicon_t * e.vicon_sigma(vicon, e.vicon).t_m if vicon is not None and e.tracked else None
    return {"sample_id": e.row["sample_id"], **g.pose_columns("kuka_cam_from_target", e.kuka),
            **g.pose_columns("vicon_cam_from_target", e.vicon if e.tracked else None), "vicon_accepted": reason is None,
            "reject_reason": reason, **g.pose_columns("cam_from_target", fused),
            "sigma_t_m": t_m, "sigma_r_rad": sigma.r_rad, "kuka_sigma_t_m": by_source.kuka_t * calibrated_kuka.t_m,
            "vicon_sigma_t_m": vicon_sigma}


def resolve(config: Config, workspace: Workspace | None = None) -> Resolved:
    """Reads the dataset session's captures and the calibration; writes ``poses`` and
    ``W/fusion.json``."""
    return Resolved(("captures", "calibration_samples"), ("fuse", "testbed", "facility.path"), {}, ("poses",))


def run(config: Config, workspace: Workspace) -> pa.Table:
    target = workspace_target(config, workspace)
    payload = arms.Payload.of(target)
    kuka, vicon, rejection = load_models(workspace, config.testbed, payload, config.fuse.vicon_scale_sigma,
                                         config.facility.path)
    # in sample_id order, not in the order acquire's workers finished: same inputs, same bytes
    # each joint's last move from every capture's readings in capture order, failed ones too
    captured = sorted((r for r in lost_motion.move_directions(read_manifest(workspace, "captures").to_pylist())
                       if r["status"] == "ok"), key=lambda r: r["sample_id"])
    rows = [r for r in captured if r["session"] == "dataset"]
    geometry, geometry_why = None, "no motion capture in this session"
    if vicon is not None:
        geometry, geometry_why, rejection = with_marker_geometry(workspace, captured, target, kuka, vicon, rejection)
    short_why = ""
    two_source = sum(measured_b(r, "vicon") is not None for r in rows) if vicon is not None else 0
    if config.fuse.sigma_scale == "dataset" and two_source < config.fuse.min_scale_samples:
        rejection, geometry, short_why = widened_for_short_session(kuka, vicon, rejection, geometry)
    # every capture's estimates first: the session's variance factor depends on all of them,
    # so an interrupted run resumes with the same factor
    covariances = kuka.parameter_covariances(rows, config.fuse)
    estimates = [estimate(row, kuka, vicon, c, geometry) for row, c in zip(rows, covariances, strict=True)]
    session = session_fusion(config, estimates, kuka, vicon, rejection)
    measured, why, offset, factor = session.measured, session.why, session.offset, session.factor
    refused, sources, axis_why = session.refused, session.sources, session.sources_why
    write_fusion(workspace, FusionRecord(
        factor_t=tuple(float(v) for v in factor.t), factor_r=float(factor.r), samples=factor.samples, why=why,
        kuka_t=tuple(float(v) for v in session.by_source.kuka_t),
        vicon_t=tuple(float(v) for v in session.by_source.vicon_t),
        rejection_k=config.fuse.rejection_k, axis_sources=sources, axis_why=axis_why, rejected=refused.count,
        rejected_bound=refused.bound,
        measured_t=tuple(float(v) for v in measured.t), offset_m=tuple(float(v) for v in offset.t_m),
        offset_sigma_m=tuple(float(v) for v in offset.sigma_m), offset_from=offset.removed_from,
        offset_why=offset.why, marker_sigma_m=None if geometry is None else geometry.marker_sigma_m,
        sigma_why=f"motion capture's fit: {geometry_why}{short_why}"))
    # one short line; why each figure is what it is stays in W/fusion.json (why, axes.why, offset.why)
    kept = [f" ({'robots' if source == 'kuka' else 'motion capture'} alone {session.by_source.of(source)[axis]:.2f})"
            if source != "fused" else "" for axis, source in enumerate(sources)]
    print(f"fuse: sigma factors x {factor.t[0]:.2f}{kept[0]} y {factor.t[1]:.2f}{kept[1]} "
          f"z {factor.t[2]:.2f}{kept[2]}, rotation {factor.r:.2f}"
          f"; position x, y, z: {', '.join(sources)}; why: {workspace.display(workspace.root / FUSION_FILE)}")
    done = read_keys(workspace, "poses")
    todo = [e for e in estimates if e.row["sample_id"] not in done]
    with open_sink(workspace, "poses", config.run.part_rows) as sink:
        for e in track(todo, len(todo), "fuse"):
            sink.add(fuse_capture(e, kuka, vicon, rejection, factor, config.fuse.rejection_k, sources, offset,
                                  session.by_source))
    return read_manifest(workspace, "poses")
