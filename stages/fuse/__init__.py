"""The fuse stage: per dataset capture, the pose from each source through its calibrated
offsets, the motion-capture rejection test, and the Bayesian fusion (docs/architecture.md section 6).

It reads the captures and ``W/calibration.json``, never the truth. The calibrated sigmas
were measured at the calibration distance and arm configurations; on the dataset
captures they grow with the lever of the line of sight, with the calibrated arms'
parameter uncertainty propagated to each capture's configuration, and by the session's
a posteriori variance factor: how much the two sources disagree on its own captures
beyond what those sigmas predict (``W/fusion.json``). On an axis where that disagreement
fails a 95% test of consistency, the source with the smaller sigma there is kept alone
(``axis_sources``): two sources cannot tell which of them is off, and fusing would let the
worse pull the better. The median difference of the two over the session is first
removed from the source with the larger sigma (``session_offset``), so that only the
capture-to-capture errors are tested and fused.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyarrow as pa

from manifests import Workspace, open_sink, read_keys, read_manifest
from manifests.sidecars import Calibration, FusionRecord, SourceCalibration, read_calibration, write_fusion
from pipeline.config import Config, FuseConfig, TestbedConfig
from pipeline.progress import track
from pipeline.stage_io import Resolved
from speedplus.errors import InputError
from stages.common import arms
from stages.common import geometry as g
from stages.common.fusion import (
    CONSISTENCY_LEVEL,
    UNIT_FACTOR,
    Sigma,
    VarianceFactor,
    at_position,
    consistency_bound,
    fuse,
    rejection_reason,
    variance_factor,
    with_scale_error,
)
from stages.common.json_arrays import matrix
from stages.common.rwhe import fixture_tilt
from stages.common.sources import measured_b, up_targetee
from stages.common.workspace_target import workspace_target


class SourceModel:
    """One source's calibrated offsets, fixture compliance and uncertainty."""

    def __init__(self, entry: SourceCalibration, calibration: Calibration, testbed: TestbedConfig,
                 payload: arms.Payload, scale_sigma: float = 0.0) -> None:
        self.z = matrix(entry.cam_from_offset)
        kinematics = entry.arm_kinematics
        self.arms = arms.ArmErrors.from_json(kinematics) if kinematics["estimated"] else None
        self.kinematics = kinematics
        self.testbed = testbed
        self.payload = payload
        self.x = {fixture: matrix(pose) for fixture, pose in entry.target_from_offset_by_fixture.items()}
        self.compliance = {fixture: np.asarray(k, float) for fixture, k in entry.compliance_k_rad.items()}
        self.anisotropy = {fixture: np.asarray(d, float) for fixture, d in entry.compliance_anisotropy.items()}
        self.sigma = Sigma.from_record(entry.sigma)
        self.calibration_lever_sq = np.array(calibration.calibration_lever_sq_m2, float)
        self.calibration_distance_m = calibration.calibration_distance_m
        self.world_up = np.asarray(calibration.world_up, float)  # the up the compliance was fitted with
        self.scale_sigma = scale_sigma

    def estimate(self, b: np.ndarray, row: dict[str, Any]) -> np.ndarray:
        """``cam_from_target`` (4, 4) of a capture from this source's measurement ``b``."""
        fixture = row["fixture"]
        if fixture not in self.x:
            raise InputError(f"captures: sample {row['sample_id']} uses fixture {fixture!r}, which the calibration "
                             f"did not see (calibrated: {', '.join(sorted(self.x))}); add calibration captures "
                             "with it")
        up = up_targetee(row, self.world_up)
        if self.arms is not None:
            readings = arms.readings([row], self.payload)
            if readings is None:
                raise InputError(f"captures: sample {row['sample_id']} lacks the robots' encoder readings, which the "
                                 "calibration of the arms needs (calibrate.arm_kinematics)")
            b_arms, up_arms = arms.corrected_b(self.testbed, self.arms, readings, self.world_up)
            b, up = b_arms[0], up_arms[0]
        if fixture in self.compliance:
            d = self.anisotropy[fixture][None] if fixture in self.anisotropy else None
            b = b @ fixture_tilt(up[None], self.compliance[fixture][None], d)[0]
        return self.z @ b @ g.invert(self.x[fixture])

    def sigma_at(self, pose: np.ndarray, sigma: Sigma | None = None) -> Sigma:
        """This source's sigma (or ``sigma``, measured at the calibration) grown to ``pose``:
        the line of sight's lever, and the distances' scale error beyond the calibration's."""
        grown = at_position(self.sigma if sigma is None else sigma, pose[:3, 3], self.calibration_lever_sq)
        return with_scale_error(grown, pose[:3, 3], self.calibration_distance_m, self.scale_sigma)

    def parameter_covariances(self, rows: list[dict[str, Any]], fuse: FuseConfig) -> list[np.ndarray | None]:
        """(6, 6) covariance of each capture's pose from the calibrated arms' uncertainty and
        the joints' lost motion (``arms.flank_variances``; None without calibrated arms);
        all captures at once."""
        if self.arms is None or not rows:
            return [None] * len(rows)
        readings = arms.readings(rows, self.payload)
        if readings is None:
            raise InputError("captures: dataset captures lack the robots' encoder readings, which the calibration "
                             "of the arms needs (calibrate.arm_kinematics)")
        flanks = arms.flank_variances(self.testbed, readings, fuse.lost_motion_rad, fuse.backlash_preload_nm)
        return list(arms.pose_covariances(self.testbed, self.kinematics, readings, [r["fixture"] for r in rows],
                                          self.world_up, flanks))


def load_models(workspace: Workspace, testbed: TestbedConfig, payload: arms.Payload,
                vicon_scale_sigma: float) -> tuple[SourceModel, SourceModel | None, Sigma | None]:
    """Both sources' calibrated models and the rejection sigma, from ``W/calibration.json``."""
    calibration = read_calibration(workspace)
    kuka = SourceModel(calibration.kuka, calibration, testbed, payload)
    vicon = rejection = None
    if calibration.vicon is not None:
        vicon = SourceModel(calibration.vicon, calibration, testbed, payload, vicon_scale_sigma)
        rejection = Sigma.from_record(calibration.rejection)
    return kuka, vicon, rejection


@dataclass(frozen=True)
class Estimates:
    """A dataset capture's pose (4, 4) from each source; ``vicon`` None when not measured."""

    row: dict[str, Any]
    kuka: np.ndarray
    vicon: np.ndarray | None
    kuka_covariance: np.ndarray | None  # (6, 6) from the calibrated arms' parameters

    @property
    def tracked(self) -> bool:
        """Motion capture gave a finite pose of this capture."""
        return self.vicon is not None and bool(np.all(np.isfinite(self.vicon)))

    def plus_parameters(self, sigma: Sigma) -> Sigma:
        """``sigma`` with the robots' parameter uncertainty at this capture added."""
        if self.kuka_covariance is None:
            return sigma
        return Sigma(np.sqrt(sigma.t_m**2 + np.diag(self.kuka_covariance)[3:]),
                     float(np.sqrt(sigma.r_rad**2 + np.trace(self.kuka_covariance[:3, :3]))), sigma.pointing_rad)


def estimate(row: dict[str, Any], kuka: SourceModel, vicon: SourceModel | None,
             kuka_covariance: np.ndarray | None) -> Estimates:
    vicon_pose = None
    if vicon is not None:
        b = measured_b(row, "vicon")
        vicon_pose = None if b is None else vicon.estimate(b, row)
    return Estimates(row, kuka.estimate(measured_b(row, "kuka"), row), vicon_pose, kuka_covariance)


def session_factor(config: Config, estimates: list[Estimates], vicon: SourceModel | None,
                   rejection: Sigma | None) -> tuple[VarianceFactor, str]:
    """The variance factor of this dataset session, and why it is what it is."""
    if vicon is None or rejection is None:
        return UNIT_FACTOR, "one source: the calibrated sigmas"
    if config.fuse.sigma_scale == "calibration":
        return UNIT_FACTOR, "fuse.sigma_scale = calibration"
    both = [e for e in estimates if e.tracked]
    if len(both) < config.fuse.min_scale_samples:
        return UNIT_FACTOR, (f"{len(both)} captures with both sources < fuse.min_scale_samples "
                             f"({config.fuse.min_scale_samples}): the calibrated sigmas")
    predicted = [e.plus_parameters(vicon.sigma_at(e.kuka, rejection)) for e in both]
    factor = variance_factor(np.stack([e.kuka for e in both]), np.stack([e.vicon for e in both]), predicted)
    return factor, f"robust spread of motion capture against the robots on {len(both)} dataset captures"


def smaller_sigma(estimates: list[Estimates], kuka: SourceModel, vicon: SourceModel) -> tuple[np.ndarray, str]:
    """Per camera axis (3,) the source whose sigma is smaller (median over the two-source
    captures; "kuka" or "vicon"), and the medians in words."""
    both = [e for e in estimates if e.tracked]
    sigma_kuka = np.median([e.plus_parameters(kuka.sigma_at(e.kuka)).t_m for e in both], axis=0)
    sigma_vicon = np.median([vicon.sigma_at(e.vicon).t_m for e in both], axis=0)
    words = ", ".join(f"{a} {k * 1000:.2f}/{v * 1000:.2f}" for a, k, v in zip("xyz", sigma_kuka, sigma_vicon,
                                                                              strict=True))
    return np.where(sigma_kuka <= sigma_vicon, "kuka", "vicon"), f"median sigma robots/motion capture (mm): {words}"


@dataclass(frozen=True)
class SessionOffset:
    """Per camera axis (m): motion capture's median excess over the robots on the session,
    its standard error, and the source it is removed from (the one whose sigma is larger)."""

    t_m: np.ndarray  # (3,)
    sigma_m: np.ndarray  # (3,)
    removed_from: tuple[str, str, str]
    why: str

    def robots(self, pose: np.ndarray) -> np.ndarray:
        """The robots' ``cam_from_target`` (4, 4), the offset added where their sigma is larger."""
        out = pose.copy()
        out[:3, 3] += np.where([source == "kuka" for source in self.removed_from], self.t_m, 0.0)
        return out

    def motion_capture(self, pose: np.ndarray) -> np.ndarray:
        """Motion capture's ``cam_from_target`` (4, 4), the offset removed where its sigma is larger."""
        out = pose.copy()
        out[:3, 3] -= np.where([source == "vicon" for source in self.removed_from], self.t_m, 0.0)
        return out


NO_OFFSET = SessionOffset(np.zeros(3), np.zeros(3), ("vicon",) * 3, "")


def session_offset(config: Config, estimates: list[Estimates], kuka: SourceModel, vicon: SourceModel | None,
                   rejection: Sigma | None, factor: VarianceFactor) -> SessionOffset:
    """The median difference (motion capture minus robots, per camera axis) over the
    session's two-source captures: a median, so that ghost markers, which the rejection test
    has not yet removed, barely move it.

    Why: both sources were calibrated at close range, so at the dataset's range each errs
    mostly by one offset per session (the rail's and the wand's scale, offsets extrapolated
    from the calibration's lever), the same on every capture. Inverse-variance fusion treats
    errors as independent from capture to capture; fusing two session offsets helps on
    average but harms wherever the better source drew the smaller one, which two sources
    cannot see. With the difference of the offsets removed from the larger-sigma source,
    the labels keep that source's own offset and fuse only what varies between captures,
    which the session's many captures do average. The standard error is the median's of
    differences with the predicted sigmas scaled by the session's factor."""
    if vicon is None or rejection is None or config.fuse.session_offset == "off":
        return dataclasses.replace(NO_OFFSET, why="one source" if vicon is None else "fuse.session_offset = off")
    both = [e for e in estimates if e.tracked]
    if len(both) < config.fuse.min_scale_samples:
        return dataclasses.replace(NO_OFFSET, why=f"{len(both)} two-source captures < "
                                   f"fuse.min_scale_samples ({config.fuse.min_scale_samples}): none removed")
    difference = np.stack([e.vicon[:3, 3] - e.kuka[:3, 3] for e in both])
    offset = np.median(difference, axis=0)
    predicted = np.stack([e.plus_parameters(vicon.sigma_at(e.kuka, rejection)).t_m for e in both])
    # a median's standard error is sqrt(pi / 2) times the mean's
    sigma = np.sqrt(np.pi / 2) * factor.t * np.sqrt(np.mean(predicted**2, axis=0) / len(both))
    larger = tuple("vicon" if source == "kuka" else "kuka" for source in smaller_sigma(estimates, kuka, vicon)[0])
    words = ", ".join(f"{a} {o * 1000:+.2f} +- {e * 1000:.2f}" for a, o, e in zip("xyz", offset, sigma, strict=True))
    return SessionOffset(offset, sigma, larger, f"median of motion capture minus robots on {len(both)} captures "
                         f"(mm): {words}; removed from {'/'.join(larger)}")


def axis_sources(config: Config, estimates: list[Estimates], kuka: SourceModel, vicon: SourceModel | None,
                 factor: VarianceFactor) -> tuple[tuple[str, str, str], str]:
    """Per camera axis, where the labels' position comes from (``AXIS_SOURCES``), and why.

    Where the two sources disagree on the dataset captures beyond their sigmas (the factor
    fails ``VarianceFactor.inconsistent``), one of them errs beyond its sigma, and two
    sources cannot tell which; fusing would let the worse pull the better. The source with
    the smaller sigma on that axis (median over the two-source captures) is kept alone: the
    calibration's ranking is the only evidence left. Its sigma is scaled by the session's
    factor, as both are where they fuse (``fuse_capture``)."""
    if vicon is None or config.fuse.inconsistent_axes == "fuse":
        return ("fused",) * 3, ("one source" if vicon is None else "fuse.inconsistent_axes = fuse")
    inconsistent = factor.inconsistent()
    smaller, medians = smaller_sigma(estimates, kuka, vicon)
    sources = tuple(str(smaller[axis]) if inconsistent[axis] else "fused" for axis in range(3))
    reasons = [f"{name}: factor {factor.t[axis]:.3f} > {consistency_bound(factor.samples):.3f} (what "
               f"{CONSISTENCY_LEVEL:.0%} of consistent sources stay under on {factor.samples} captures): "
               f"{sources[axis]} alone" for axis, name in enumerate("xyz") if inconsistent[axis]]
    if not reasons:
        return sources, "the sources agree within their sigmas on every axis"
    return sources, f"{'; '.join(reasons)} ({medians})"


def fuse_capture(e: Estimates, kuka: SourceModel, vicon: SourceModel | None, rejection: Sigma | None,
                 factor: VarianceFactor, rejection_k: float, sources: tuple[str, ...] = ("fused",) * 3,
                 offset: SessionOffset = NO_OFFSET) -> dict[str, Any]:
    """One ``poses`` row; ``sources``: per camera axis, fused or one source alone
    (``axis_sources``); ``offset``: removed before fusing (``session_offset``)."""
    calibrated_kuka = e.plus_parameters(kuka.sigma_at(e.kuka))
    # both in the offset of the source with the smaller sigma: tested and fused on what
    # varies from capture to capture only, and a robots-only label in the session's offset
    kuka_pose = offset.robots(e.kuka)
    vicon_pose = offset.motion_capture(e.vicon) if e.tracked else e.vicon
    reason = "no motion capture in this session"
    if vicon is not None:
        predicted = e.plus_parameters(vicon.sigma_at(e.kuka, rejection))
        reason = rejection_reason(kuka_pose, vicon_pose, factor.scale(predicted), rejection_k)
    if reason is None:
        calibrated_vicon = vicon.sigma_at(e.vicon)
        fused, sigma = fuse(kuka_pose, factor.scale(calibrated_kuka), vicon_pose, factor.scale(calibrated_vicon))
    else:
        fused, sigma = kuka_pose.copy(), factor.scale(calibrated_kuka)
    t_m = sigma.t_m.copy()
    for axis, source in enumerate(sources):
        if source != "fused":  # motion capture alone where it passed the rejection test, else the robots
            mocap = source == "vicon" and reason is None
            pose, alone = (vicon_pose, calibrated_vicon) if mocap else (kuka_pose, calibrated_kuka)
            # the session's factor scales the kept source as it scales both where they fuse:
            # which of the two the disagreement's excess belongs to cannot be told
            fused[axis, 3], t_m[axis] = pose[axis, 3], factor.t[axis] * alone.t_m[axis]
    return {"sample_id": e.row["sample_id"], **g.pose_columns("kuka_cam_from_target", e.kuka),
            **g.pose_columns("vicon_cam_from_target", e.vicon if e.tracked else None), "vicon_accepted": reason is None,
            "reject_reason": reason, **g.pose_columns("cam_from_target", fused),
            "sigma_t_m": t_m, "sigma_r_rad": sigma.r_rad}



def resolve(config: Config, workspace: Workspace | None = None) -> Resolved:
    """Reads the dataset session's captures and the calibration; writes ``poses`` and
    ``W/fusion.json``."""
    return Resolved(("captures", "calibration_samples"), ("fuse", "testbed"), {}, ("poses",))


def run(config: Config, workspace: Workspace) -> pa.Table:
    payload = arms.Payload.of(workspace_target(config, workspace))
    kuka, vicon, rejection = load_models(workspace, config.testbed, payload, config.fuse.vicon_scale_sigma)
    # in sample_id order, not in the order acquire's workers finished: same inputs, same bytes
    rows = sorted((r for r in read_manifest(workspace, "captures").to_pylist()
                   if r["session"] == "dataset" and r["status"] == "ok"), key=lambda r: r["sample_id"])
    # every capture's estimates first: the session's variance factor depends on all of them,
    # so an interrupted run resumes with the same factor
    covariances = kuka.parameter_covariances(rows, config.fuse)
    estimates = [estimate(row, kuka, vicon, c) for row, c in zip(rows, covariances, strict=True)]
    factor, why = session_factor(config, estimates, vicon, rejection)
    sources, axis_why = axis_sources(config, estimates, kuka, vicon, factor)
    offset = session_offset(config, estimates, kuka, vicon, rejection, factor)
    write_fusion(workspace, FusionRecord(tuple(float(v) for v in factor.t), float(factor.r), factor.samples, why,
                                         config.fuse.rejection_k, sources, axis_why,
                                         tuple(float(v) for v in offset.t_m), tuple(float(v) for v in offset.sigma_m),
                                         offset.removed_from, offset.why))
    print(f"fuse: sigma factors: position x {factor.t[0]:.2f} y {factor.t[1]:.2f} z {factor.t[2]:.2f}, "
          f"rotation {factor.r:.2f} ({why}); position x, y, z: {', '.join(sources)} ({axis_why}); "
          f"offset: {offset.why}")
    done = read_keys(workspace, "poses")
    todo = [e for e in estimates if e.row["sample_id"] not in done]
    with open_sink(workspace, "poses", config.run.part_rows) as sink:
        for e in track(todo, len(todo), "fuse"):
            sink.add(fuse_capture(e, kuka, vicon, rejection, factor, config.fuse.rejection_k, sources, offset))
    return read_manifest(workspace, "poses")
