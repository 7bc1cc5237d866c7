"""What honest sigmas would show on one facility, from the method's own error model.

A facility's labels share one calibration: the arms' fitted parameters err by one draw,
which reaches every capture through its own configuration (``identification.pose_jacobians``), so
48 labels are far from 48 independent draws, most of all in depth. This simulates a
facility's label errors as the model says they are: the parameters' posterior covariance
(shared by all captures), each capture's joint lost motion and calibrated noise, motion
capture's noise and its session offset removed by the median, fused with the weights fuse
uses; each label's sigma is its simulated error's spread, honest by construction. What it
gives per camera axis (how often a facility falls outside the per-facility bands, where
the seen rms falls among honest facilities, the pooled range over many facilities) is the
yardstick of ``bench honesty``'s second table.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from manifests import Workspace, read_manifest
from manifests.sidecars import read_fusion
from pipeline.config import load_config
from stages.common import arms
from stages.common.robots import identification, lost_motion
from stages.common.workspace_target import workspace_target
from stages.fuse.stage import estimate, load_models, with_marker_geometry

#: the issue's bands for honest sigmas per facility (pooled: 90-99% inside, rms 0.8-1.2)
FACILITY_BANDS = {"inside": (0.85, 1.0), "rms": (0.7, 1.4)}


@dataclass(frozen=True)
class HonestDraws:
    """Per simulated facility (draws, 3): mean square and share inside 1.96 sigma of
    error / sigma per camera axis, on ``labels`` labels."""

    mean_square: np.ndarray
    inside: np.ndarray
    labels: int

    def probabilities(self) -> dict[str, np.ndarray]:
        """Per axis (3,): the probability that an honest facility falls outside each band."""
        rms = np.sqrt(self.mean_square)
        return {"rms under": np.mean(rms < FACILITY_BANDS["rms"][0], axis=0),
                "rms over": np.mean(rms > FACILITY_BANDS["rms"][1], axis=0),
                "inside under": np.mean(self.inside < FACILITY_BANDS["inside"][0], axis=0)}

    def percentile(self, seen_rms: np.ndarray) -> np.ndarray:
        """Per axis (3,): the share of honest facilities whose rms is below the one seen
        (uniform over facilities when the sigmas are honest; low when conservative)."""
        return np.mean(np.sqrt(self.mean_square) < np.asarray(seen_rms)[None], axis=0)


@dataclass(frozen=True)
class FacilityModel:
    """A facility's labels as the method models their errors, N captures."""

    jacobian: np.ndarray  # (N, 3, P) m per unit of each calibrated arm parameter
    covariance: np.ndarray  # (P, P) the parameters' posterior
    joint_variance_rad2: np.ndarray  # (N, K) each capture's lost motion, per joint of both robots
    joint_columns: np.ndarray  # (K,) those joints' columns of ``jacobian``
    calibrated_m: np.ndarray  # (N, 3) the robots' own sigma, independent between captures
    vicon_m: np.ndarray  # (N, 3) motion capture's sigma (0 where it did not track)
    vicon_weight: np.ndarray  # (N, 3) motion capture's share of each label (0: not fused)
    offset_removed: bool  # fuse removed the session's median difference from motion capture


def simulate(root: Path, draws: int = 2000, seed: int = 28) -> HonestDraws:
    """``draws`` honest facilities like the one in ``root``."""
    return draw(facility_model(root), draws, seed)


def facility_model(root: Path) -> FacilityModel:
    """The facility in ``root`` as modelled: its captures, calibration, fall-back axes and
    motion-capture decisions."""
    workspace = Workspace(root)
    config = load_config(None, root / "config.toml")
    payload = arms.Payload.of(workspace_target(config, workspace))
    target = workspace_target(config, workspace)
    kuka, vicon, rejection = load_models(workspace, config.testbed, payload, config.fuse.vicon_scale_sigma,
                                         config.facility.path)
    accepted = {r["sample_id"]: r["vicon_accepted"] for r in read_manifest(workspace, "poses").to_pylist()}
    every = lost_motion.move_directions(read_manifest(workspace, "captures").to_pylist())
    captured = sorted((r for r in every if r["status"] == "ok"), key=lambda r: r["sample_id"])
    geometry = None
    if vicon is not None:  # motion capture's sigma as fuse has it: its fit's geometry at each capture
        geometry = with_marker_geometry(workspace, captured, target, kuka, vicon, rejection)[0]
    rows = sorted((r for r in every
                   if r["session"] == "dataset" and r["status"] == "ok" and r["sample_id"] in accepted),
                  key=lambda r: r["sample_id"])
    if kuka.holders is None:
        raise SystemExit(f"{root}: the arms were not calibrated; the model has no parameter covariance")
    measured = identification.measured(kuka.holders, rows, payload, kuka.world_up, kuka.preload_nm)
    jacobian = identification.pose_jacobians(kuka.holders, kuka.kinematics.chains, measured, kuka.world_up)[:, 3:]
    flanks = lost_motion.flank_variances(kuka.holders, measured, kuka.kinematics.chains,
                                         None if config.facility.path else config.fuse.lost_motion_rad,
                                         kuka.parameter_scale)
    covariances = kuka.parameter_covariances(rows, config.fuse)
    estimates = [estimate(row, kuka, vicon, c, geometry) for row, c in zip(rows, covariances, strict=True)]
    sigma_kuka = np.stack([e.plus_parameters(kuka.sigma_at(e.kuka)).t_m for e in estimates])
    fusion = read_fusion(workspace)
    fused = np.array([accepted[r["sample_id"]] for r in rows])[:, None] & np.array(
        [source == "fused" for source in fusion.axis_sources])[None]  # (N, 3)
    sigma_vicon = np.stack([e.vicon_sigma(vicon, e.vicon).t_m if vicon is not None and e.tracked else np.zeros(3)
                            for e in estimates])
    weight = np.where(fused, sigma_kuka**2 / np.maximum(sigma_kuka**2 + sigma_vicon**2, 1e-300), 0.0)
    return FacilityModel(jacobian, np.asarray(kuka.kinematics.covariance), flanks,
                         identification.joint_columns(kuka.holders),
                         np.stack([kuka.sigma_at(e.kuka).t_m for e in estimates]), sigma_vicon, weight,
                         config.fuse.session_offset == "on" and vicon is not None)


def draw(model: FacilityModel, draws: int, seed: int) -> HonestDraws:
    """Simulated label errors of ``draws`` facilities like ``model``, each over its own
    honest sigma (the error's spread over the draws)."""
    rng = np.random.default_rng(seed)
    captures = len(model.jacobian)
    parameters = rng.multivariate_normal(np.zeros(len(model.covariance)), model.covariance, size=draws,
                                         method="eigh")
    robots = np.einsum("nap,dp->dna", model.jacobian, parameters)  # one draw shared by the captures
    joints = rng.standard_normal((draws,) + model.joint_variance_rad2.shape) * np.sqrt(model.joint_variance_rad2)[None]
    robots += np.einsum("nap,dnp->dna", model.jacobian[:, :, model.joint_columns], joints)
    robots += rng.standard_normal(robots.shape) * model.calibrated_m[None]
    difference = rng.standard_normal(robots.shape) * model.vicon_m[None] - robots
    fused = model.vicon_weight > 0
    if model.offset_removed:
        centre = np.stack([np.median(difference[:, fused[:, axis], axis], axis=1) if fused[:, axis].any()
                           else np.zeros(draws) for axis in range(3)], axis=1)
        difference -= centre[:, None]
    errors = robots + model.vicon_weight[None] * difference
    # each label's honest sigma is its error's spread over the draws: whatever fuse's
    # formula says, these sigmas hold, and only how the labels share errors is left
    normalised = errors / np.sqrt(np.mean(errors**2, axis=0))[None]
    return HonestDraws(np.mean(normalised**2, axis=1), np.mean(np.abs(normalised) <= 1.96, axis=1), captures)


def pooled_range(facilities: list[HonestDraws], seed: int = 28) -> dict[str, np.ndarray]:
    """Per axis (3,): the 2.5-97.5% range of the pooled share inside and rms over these
    facilities, each an honest draw of its own kind, labels weighted alike."""
    rng = np.random.default_rng(seed)
    draws = min(len(f.mean_square) for f in facilities)
    picks = [f.mean_square[rng.permutation(draws)] for f in facilities]
    inside = [f.inside[rng.permutation(draws)] for f in facilities]
    labels = np.array([f.labels for f in facilities], float)[:, None, None]
    square = np.sum(np.stack(picks) * labels, axis=0) / labels.sum()
    share = np.sum(np.stack(inside) * labels, axis=0) / labels.sum()
    return {"rms": np.quantile(np.sqrt(square), [0.025, 0.975], axis=0),
            "inside": np.quantile(share, [0.025, 0.975], axis=0)}
