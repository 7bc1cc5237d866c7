"""Kinematic calibration of the two arms: joint zero offsets, link lengths, base poses and
the rail scale, estimated with the RWHE offsets from the calibration captures.

Why: RWHE alone fits one ``Z`` and one ``X_f`` that absorb the arms' errors only at the
calibration session's arm configurations (camera 0.75 m from the board). The dataset
session puts the arms elsewhere (camera 3-5 m from the model), where the uncorrected
pose-dependent errors reappear: about 0.14 deg of pointing on the default profile, 10 mm
at 4 m. Correcting the arms' own parameters carries the calibration over.

Model. The controller reports the nominal forward kinematics of its encoder readings
``q``; the true flange is ``base_c(rail * (1 + s)) @ E_c @ FK(arm_c + dl_c, q_c + dq_c)``
for the camera robot on its rail, and ``base_t @ E_t @ FK(arm_t + dl_t, q_t + dq_t)`` for
the target robot, with ``E`` a small base correction (rotation vector, translation).
Then ``B_i = camee_from_targetee`` follows from the readings, and the robots' RWHE is
``A_i X_f = Z B_i(p) S((I + D_f)(up_i x k_f))`` over ``p``, ``Z``, ``X_f`` (and ``k_f``,
``D_f``: the fixture's compliance and its anisotropy, ``rwhe.fixture_tilt``, with a
zero-mean prior ``calibrate.fixture_anisotropy_prior`` on ``D_f``). Several of
these parameters are not separable from each other or from ``Z``/``X_f`` (A6's offset
turns the flange like a rotation of ``Z``; A1's offset of the floor robot like a turn of
its base about z): Gaussian priors of the lab's tolerances (``calibrate.arm_prior_*``)
make the problem well posed (a maximum a posteriori estimate).

Joint compliance. Gearboxes wind up under load: the links of A2, A3 and A5, which carry
the arms' and payloads' weight, turn past their encoders by ``c_j tau_j(q)``. The torques
come from the lab's nominal mass model (``stages.common.statics``, the testbed's payload
masses); the compliances ``c_j`` are estimated with a zero-mean prior as wide as the
arm class's values (``calibrate.arm_prior_compliance_rad_per_nm``): joint stiffness is the
first non-geometric parameter of robot calibration (Dumas et al. 2011), and it is what
carries the calibration from the board at 0.75 m to the dataset's arm configurations,
where the gravity torques differ. Torques are evaluated at the nominal arm (the change
from the corrected one is of second order).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Protocol

import numpy as np
from scipy.optimize import least_squares

from core.config import TestbedConfig
from manifests.sidecars.arm_fit import ARM_LINKS, COMPLIANCE_KEYS, ArmCorrections, ArmFit, BaseCorrection
from stages.common import geometry as g
from stages.common import layout, rwhe
from stages.common.kinematics import arm_model, forward
from stages.common.statics import gravity_torques, link_masses
from stages.common.target import Target

#: mean square of a unit's lost motion over its rating's square: uniform on 50-100% of it
UNIT_SHARE = 7 / 12
#: the joints whose compliance is estimated (A2, A3, A5: those gravity loads)
COMPLIANT_JOINTS = (1, 2, 4)


class ArmLayout:
    """Where each of the arms' parameters sits in their packed vector (``ArmErrors.params``,
    (N_ARM,)): one named slice per group, in this order."""

    camera_joint_offsets = slice(0, 6)  # rad, A1-A6
    target_joint_offsets = slice(6, 12)
    camera_link_deltas = slice(12, 18)  # m, in the order of ARM_LINKS
    target_link_deltas = slice(18, 24)
    camera_base = slice(24, 30)  # rotation vector (rad) then translation (m) of the base's correction
    target_base = slice(30, 36)
    rail_scale = slice(36, 37)  # the rail's scale error (1)
    camera_compliance = slice(37, 40)  # rad / (N m), of the COMPLIANT_JOINTS
    target_compliance = slice(40, 43)
    compliance = slice(37, 43)  # both robots'
    joint_offsets = slice(0, 12)  # both robots'


#: parameters of the arms: joint offsets (6 + 6), link lengths (6 + 6), bases (6 + 6), rail scale,
#: joint compliances (3 + 3)
N_ARM = ArmLayout.target_compliance.stop


@dataclass(frozen=True)
class Payload:
    """What the target robot carries: the mock-up's mass (kg), its body centre (its weight)
    (3,) in T at mock-up scale (m) and, per fixture, in the nominal target flange frame
    (``Payload.of`` a target)."""

    mass_kg: float
    centre_m: tuple[float, float, float]
    centre_in_flange_m: tuple[tuple[str, tuple[float, float, float]], ...]

    @classmethod
    def of(cls, target: Target) -> Payload:
        centre = np.asarray(target.centre_m, float) * target.mockup_scale
        in_flange = {mount: g.apply(g.invert(layout.target_from_targetee(target, mount)), centre[None])[0]
                     for mount in layout.MOUNT_NAMES}
        return cls(float(target.mockup_mass_kg), (float(centre[0]), float(centre[1]), float(centre[2])),
                   tuple((mount, tuple(float(v) for v in point)) for mount, point in in_flange.items()))

    def centre_in_flange(self, fixture: str) -> np.ndarray:
        """(3,) m: the body centre in the flange frame of ``fixture`` (one the layout does not
        know is taken as the minus_x mount)."""
        known = dict(self.centre_in_flange_m)
        return np.array(known.get(fixture, known[layout.MOUNT_NAMES[0]]), float)


@dataclass(frozen=True)
class Readings:
    """Encoder readings of the captures: joints (N, 6) rad of each robot, rail (N,) m, the
    model fixture of each (it decides where the model's weight hangs) and the payload."""

    camera_joints_rad: np.ndarray
    target_joints_rad: np.ndarray
    rail_m: np.ndarray
    payload: Payload
    fixtures: tuple[str, ...] = ()

    def subset(self, mask: np.ndarray) -> Readings:
        fixtures = tuple(f for f, keep in zip(self.fixtures, mask, strict=True) if keep) if self.fixtures else ()
        return Readings(self.camera_joints_rad[mask], self.target_joints_rad[mask], self.rail_m[mask], self.payload,
                        fixtures)


def readings(rows: list[dict[str, Any]], payload: Payload) -> Readings | None:
    """The captures' encoder readings, or None when any capture lacks them."""
    keys = ("kuka_camera_joints_rad", "kuka_target_joints_rad", "kuka_rail_m")
    if not rows or any(row.get(key) is None for row in rows for key in keys):
        return None
    return Readings(np.array([r["kuka_camera_joints_rad"] for r in rows], float),
                    np.array([r["kuka_target_joints_rad"] for r in rows], float),
                    np.array([r["kuka_rail_m"] for r in rows], float), payload,
                    tuple(str(r.get("fixture") or "fixed") for r in rows))


@lru_cache(maxsize=32)
def _torques(testbed: TestbedConfig, payload: Payload, camera: bytes, target: bytes, rail: bytes,
             fixtures: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    arm, masses = arm_model(testbed.robot_model), link_masses(testbed.robot_model)
    camera_joints = np.frombuffer(camera).reshape(-1, 6)
    target_joints = np.frombuffer(target).reshape(-1, 6)
    rail_m = np.frombuffer(rail)
    fixtures = fixtures or ("fixed",) * len(rail_m)
    camera_payload = 0.5 * np.asarray(testbed.camee_from_cam_t_m, float)  # camera body: halfway to the lens
    camera_torque, target_torque = np.zeros((len(rail_m), 6)), np.zeros((len(rail_m), 6))
    for i, (q_camera, q_target, rail_i, fixture) in enumerate(zip(camera_joints, target_joints, rail_m, fixtures,
                                                                   strict=True)):
        camera_torque[i] = gravity_torques(arm, masses, layout.world_from_camera_base(testbed, rail_i), q_camera,
                                           testbed.camera_payload_kg, camera_payload)
        target_torque[i] = gravity_torques(arm, masses, layout.world_from_target_base(testbed), q_target,
                                           payload.mass_kg, payload.centre_in_flange(fixture))
    return camera_torque, target_torque


def torques(testbed: TestbedConfig, r: Readings) -> tuple[np.ndarray, np.ndarray]:
    """Nominal gravity torques (N, 6) N m of the camera and target robots at readings ``r``."""
    return _torques(testbed, r.payload, np.ascontiguousarray(r.camera_joints_rad, float).tobytes(),
                    np.ascontiguousarray(r.target_joints_rad, float).tobytes(),
                    np.ascontiguousarray(r.rail_m, float).tobytes(), tuple(r.fixtures))


@dataclass(frozen=True)
class ArmErrors:
    """The arms' estimated corrections (see the module docstring); zero: the nominal testbed."""

    params: np.ndarray  # (N_ARM,): joint offsets (camera, target), link deltas (camera, target), bases, rail,
    # compliances of A2, A3, A5 (camera, target)

    def record(self) -> ArmCorrections:
        """The corrections by name, as calibration.json keeps them."""
        p, at = [float(v) for v in self.params], ArmLayout
        camera_base, target_base = p[at.camera_base], p[at.target_base]
        return ArmCorrections(
            tuple(p[at.camera_joint_offsets]), tuple(p[at.target_joint_offsets]),
            dict(zip(ARM_LINKS, p[at.camera_link_deltas], strict=True)),
            dict(zip(ARM_LINKS, p[at.target_link_deltas], strict=True)),
            BaseCorrection(tuple(camera_base[:3]), tuple(camera_base[3:])),
            BaseCorrection(tuple(target_base[:3]), tuple(target_base[3:])), p[at.rail_scale][0],
            dict(zip(COMPLIANCE_KEYS, p[at.camera_compliance], strict=True)),
            dict(zip(COMPLIANCE_KEYS, p[at.target_compliance], strict=True)))

    @classmethod
    def from_record(cls, c: ArmCorrections) -> ArmErrors:
        p = [*c.camera_joint_offsets_rad, *c.target_joint_offsets_rad,
             *(c.camera_link_deltas_m[n] for n in ARM_LINKS), *(c.target_link_deltas_m[n] for n in ARM_LINKS),
             *c.camera_base_correction.rotvec_rad, *c.camera_base_correction.t_m,
             *c.target_base_correction.rotvec_rad, *c.target_base_correction.t_m, c.rail_scale_error,
             *(c.camera_compliance_rad_per_nm[n] for n in COMPLIANCE_KEYS),
             *(c.target_compliance_rad_per_nm[n] for n in COMPLIANCE_KEYS)]
        return cls(np.array(p, float))


NOMINAL = ArmErrors(np.zeros(N_ARM))


def flanges(testbed: TestbedConfig, errors: ArmErrors, r: Readings) -> tuple[np.ndarray, np.ndarray]:
    """``world_from_camee`` and ``world_from_targetee`` (N, 4, 4) of the readings."""
    world_from_camee, world_from_targetee = _flanges(testbed, errors.params[None], r)
    return world_from_camee[0], world_from_targetee[0]


def _flanges(testbed: TestbedConfig, p: np.ndarray, r: Readings) -> tuple[np.ndarray, np.ndarray]:
    """``flanges`` (K, N, 4, 4) of a batch of arm parameters (K, N_ARM) at once."""
    nominal = arm_model(testbed.robot_model)
    at = ArmLayout
    camera_links = r.camera_joints_rad + p[:, None, at.camera_joint_offsets]
    target_links = r.target_joints_rad + p[:, None, at.target_joint_offsets]
    if np.any(p[:, at.compliance]):
        camera_torque, target_torque = torques(testbed, r)
        compliance = np.zeros((len(p), 2, 6))
        compliance[:, :, COMPLIANT_JOINTS] = p[:, at.compliance].reshape(-1, 2, 3)
        camera_links = camera_links + compliance[:, None, 0] * camera_torque
        target_links = target_links + compliance[:, None, 1] * target_torque
    world_from_camee = (layout.world_from_camera_base(testbed, r.rail_m * (1.0 + p[:, at.rail_scale]))
                        @ rwhe.transform_from_vector(p[:, None, at.camera_base])
                        @ forward(nominal, camera_links, p[:, None, at.camera_link_deltas]))
    world_from_targetee = (layout.world_from_target_base(testbed)
                           @ rwhe.transform_from_vector(p[:, None, at.target_base])
                           @ forward(nominal, target_links, p[:, None, at.target_link_deltas]))
    return world_from_camee, world_from_targetee


def corrected_b(testbed: TestbedConfig, errors: ArmErrors, r: Readings,
                world_up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The robots' ``B`` = ``camee_from_targetee`` (N, 4, 4) and the up direction in the
    target flange frame (N, 3) from the readings, with the arms corrected by ``errors``."""
    world_from_camee, world_from_targetee = flanges(testbed, errors, r)
    up = np.einsum("nji,j->ni", world_from_targetee[:, :3, :3], np.asarray(world_up, float))
    return g.invert(world_from_camee) @ world_from_targetee, up


class ArmFitSettings(Protocol):
    """What ``fit`` reads of its caller's settings (the calibrate stage's section,
    stages/calibrate/config.py, whose fields' help gives their meaning and units)."""

    world_up: tuple[float, float, float]
    arm_prior_joint_rad: float
    arm_prior_length_m: float
    arm_prior_base_m: float
    arm_prior_base_rad: float
    arm_prior_rail_scale: float
    arm_prior_compliance_rad_per_nm: tuple[float, float, float]
    joint_compliance: str
    fixture_anisotropy: str
    fixture_anisotropy_prior: float


def priors(c: ArmFitSettings) -> np.ndarray:
    """1-sigma of each arm parameter before calibration (N_ARM,)."""
    at, sigma = ArmLayout, np.empty(N_ARM)
    sigma[at.joint_offsets] = c.arm_prior_joint_rad
    sigma[at.camera_link_deltas] = sigma[at.target_link_deltas] = c.arm_prior_length_m
    for base in (at.camera_base, at.target_base):
        sigma[base] = [c.arm_prior_base_rad] * 3 + [c.arm_prior_base_m] * 3
    sigma[at.rail_scale] = c.arm_prior_rail_scale
    sigma[at.compliance] = list(c.arm_prior_compliance_rad_per_nm) * 2
    return sigma


def predict(testbed: TestbedConfig, params: np.ndarray, names: list[str], compliant: bool, r: Readings,
            fixtures: list[str], world_up: np.ndarray) -> np.ndarray:
    """``cam_from_target`` (N, 4, 4) of readings ``r`` from the packed parameters of ``fit``
    (arms, then ``rwhe.pack`` of the offsets of fixtures ``names``; compliant fixtures are
    anisotropic here)."""
    return predict_batch(testbed, np.asarray(params, float)[None], names, compliant, r, fixtures, world_up)[0]


def predict_batch(testbed: TestbedConfig, params: np.ndarray, names: list[str], compliant: bool, r: Readings,
                  fixtures: list[str], world_up: np.ndarray) -> np.ndarray:
    """``predict`` (K, N, 4, 4) of a batch of packed parameters (K, P) in one evaluation."""
    world_from_camee, world_from_targetee = _flanges(testbed, params[:, :N_ARM], r)
    up = np.einsum("knji,j->kni", world_from_targetee[..., :3, :3], np.asarray(world_up, float))
    b = g.invert(world_from_camee) @ world_from_targetee
    return rwhe.predict_packed(params[:, N_ARM:], names, compliant, compliant, b, fixtures, up if compliant else None)


def _forward_differences(function: Callable[[np.ndarray], np.ndarray], x: np.ndarray) -> np.ndarray:
    """The Jacobian (M, P) of a batched residual function ((K, P) -> (K, M)) at ``x`` (P,)
    by forward differences, with the steps of SciPy's ``2-point`` scheme (relative
    sqrt(eps), rounded to a representable difference), every step evaluated in one batch."""
    step = np.sqrt(np.finfo(float).eps) * np.where(x >= 0, 1.0, -1.0) * np.maximum(1.0, np.abs(x))
    batch = np.repeat(x[None], len(x) + 1, axis=0)
    batch[1 + np.arange(len(x)), np.arange(len(x))] = x + step
    values = function(batch)
    return ((values[1:] - values[0]) / ((x + step) - x)[:, None]).T


@dataclass(frozen=True)
class Fit:
    """The fitted offsets and arms, the packed parameters and their covariance."""

    offsets: rwhe.Solution
    errors: ArmErrors
    params: np.ndarray
    covariance: np.ndarray  # (P, P), from the Gauss-Newton information at the optimum
    names: list[str]
    compliant: bool

    def record(self) -> ArmFit:
        """The fit as calibration.json keeps it (``arm_kinematics``)."""
        return ArmFit(self.errors.record(), tuple(self.names), self.compliant, tuple(float(v) for v in self.params),
                      tuple(tuple(row) for row in self.covariance.tolist()))


def flank_variances(testbed: TestbedConfig, r: Readings, lost_motion_rad: tuple[float, ...],
                    preload_nm: float) -> np.ndarray:
    """(N, 12) variance (rad^2) of each joint's angle (camera A1-A6, then target) at
    readings ``r`` from its gearbox's lost motion (6,) rad, both arms alike.

    A joint whose nominal gravity torque exceeds ``preload_nm`` rests on its loaded flank,
    at the same place for every capture with that load, which the joint offsets absorb:
    none. Any other rests on the flank its last move left it on, ``+-l / 2`` from the
    middle, which no calibration can know for a capture. The data sheet's ``lost_motion_rad``
    is a rating, a maximum: a unit's ``l`` is taken as uniform between half of it and all
    of it, so the variance is ``E[l^2] / 4 = 7 / 12 (lost / 2)^2``. At 4 m a wrist's
    arcminute turns the line of sight by 0.6 mm, five times what it does to the board at
    the calibration's 0.75 m."""
    camera_torque, target_torque = torques(testbed, r)
    free = np.abs(np.concatenate([camera_torque, target_torque], axis=1)) <= preload_nm
    return np.where(free, np.tile(UNIT_SHARE * (np.asarray(lost_motion_rad, float) / 2) ** 2, 2), 0.0)


def pose_jacobians(testbed: TestbedConfig, fit: ArmFit, r: Readings, fixtures: list[str],
                   world_up: np.ndarray, step: float = 1e-7) -> np.ndarray:
    """(N, 6, P) derivatives of the poses predicted for captures ``r`` (rotation applied on
    the camera side, rad; translation, m) with respect to the fitted parameters
    (``Fit.record``), by forward differences, every step in one batch. The first 12
    columns, the joint offsets, are exactly those of the joint angles."""
    params = np.asarray(fit.parameters, float)
    names, compliant = list(fit.fixtures), fit.compliant
    moved = np.repeat(params[None], len(params) + 1, axis=0)
    moved[1 + np.arange(len(params)), np.arange(len(params))] += step
    centre, *poses = predict_batch(testbed, moved, names, compliant, r, fixtures, world_up)
    poses = np.stack(poses)  # (P, N, 4, 4)
    jacobian = np.zeros((len(fixtures), 6, len(params)))
    jacobian[:, :3] = np.moveaxis(g.matrix_to_rotvec(poses[..., :3, :3] @ np.swapaxes(centre[:, :3, :3], -1, -2)),
                                  0, -1) / step
    jacobian[:, 3:] = np.moveaxis(poses[..., :3, 3] - centre[:, :3, 3], 0, -1) / step
    return jacobian


def pose_covariance_parts(jacobian: np.ndarray, parameters: np.ndarray,
                          joint_variance_rad2: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(N, 6, 6) twice (rotation applied on the camera side, rad; translation, m), from the
    poses' Jacobians (N, 6, P) by the fitted parameters (``pose_jacobians``): the
    covariance from the parameters' covariance ``parameters`` (P, P), one draw shared by
    every capture of the session, which grows where the arms' configuration differs from
    the calibration's; and each capture's own, from the noise of its joint angles
    ``joint_variance_rad2`` (N, 12) (``flank_variances``; zeros without)."""
    shared = jacobian @ parameters @ np.swapaxes(jacobian, -1, -2)
    own = np.zeros_like(shared)
    if joint_variance_rad2 is not None:
        joints = jacobian[:, :, ArmLayout.joint_offsets]  # the camera's then the target's
        own = np.einsum("nij,nj,nkj->nik", joints, joint_variance_rad2, joints)
    return tuple(0.5 * (c + np.swapaxes(c, -1, -2)) for c in (shared, own))  # exactly symmetric despite rounding


def pose_covariances(testbed: TestbedConfig, fit: ArmFit, r: Readings, fixtures: list[str],
                     world_up: np.ndarray, joint_variance_rad2: np.ndarray | None = None,
                     step: float = 1e-7) -> np.ndarray:
    """(N, 6, 6) covariances of the poses predicted for captures ``r``: both parts of
    ``pose_covariance_parts`` together."""
    jacobian = pose_jacobians(testbed, fit, r, fixtures, world_up, step)
    shared, own = pose_covariance_parts(jacobian, np.asarray(fit.covariance, float), joint_variance_rad2)
    return shared + own


#: the arms' fit stops re-estimating its residual scales when they move by less than this
_SCALES_SETTLED = 0.05
_MAX_FITS = 4


def _redundancy_scales(difference: np.ndarray, jacobian: np.ndarray) -> np.ndarray:
    """(3, 4) scales of the twist residuals (N, 3, 4) (rotation vector in column 0,
    translation in column 3) by Helmert's variance components: each group's sum of squares
    over its redundancy, from the whitened ``jacobian`` (M, F) whose first 6 N rows are
    the residuals (rotation and translation alternating)."""
    information = np.linalg.pinv(jacobian.T @ jacobian)
    data = jacobian[:6 * len(difference)]
    leverage = np.einsum("ij,jk,ik->i", data, information, data)
    scales = []
    for column, absorbed in ((0, leverage[0::2].sum()), (3, leverage[1::2].sum())):
        entries = difference[:, :3, column]
        redundancy = max(entries.size - float(absorbed), 1.0)
        scales.append(max(float(np.sqrt(np.sum(entries**2) / redundancy)), 1e-12))
    return np.concatenate([np.full((3, 3), scales[0]), np.full((3, 1), scales[1])], axis=1)


def _residual_scales(difference: np.ndarray, twist: bool = False) -> np.ndarray:
    """(3, 4) RMS of the Frobenius residuals (N, 4, 4): one for the rotation entries, one
    for the translation entries (m); with ``twist``, of the rotation vectors in column 0."""
    rotation_entries = difference[:, :3, :1] if twist else difference[:, :3, :3]
    rotation = max(float(np.sqrt(np.mean(rotation_entries ** 2))), 1e-12)
    translation = max(float(np.sqrt(np.mean(difference[:, :3, 3] ** 2))), 1e-12)
    return np.concatenate([np.full((3, 3), rotation), np.full((3, 1), translation)], axis=1)


def map_fit(batch: Callable[[np.ndarray], np.ndarray], a: np.ndarray, params: np.ndarray, free: np.ndarray,
            prior: np.ndarray, priored: np.ndarray, twist: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """The maximum a posteriori parameters (P,) and their covariance (P, P) of any arms'
    model: ``batch`` predicts ``cam_from_target`` (K, N, 4, 4) of packed parameters (K, P),
    ``a`` (N, 4, 4) the PnP poses, ``params`` (P,) the start, ``free`` (P,) bool the ones
    estimated (the rest stay as they start, with no covariance), ``prior`` the 1-sigma of
    the free parameters at indices ``priored`` (zero-mean priors). The two residual scales
    are re-estimated from each fit until they settle (``fit``'s docstring says why).

    The residuals are the paper's Frobenius entries, or with ``twist`` each pose's rotation
    vector (rad) and translation (m): a rotation's nine matrix entries carry its three
    degrees of freedom, so weighing them as nine independent residuals takes three times
    the information they hold, and the covariance of a rotation-driven parameter comes out
    sqrt(3) too narrow. With ``twist`` the scales are also estimated from the residuals'
    redundancy (Helmert's variance components: each group's sum of squares over its count
    less the parameters it absorbs, the trace of its block of the hat matrix): a model of
    many parameters fitted to few poses leaves residuals smaller than the noise, and a
    scale taken from them alone would weigh the data ever higher, fit after fit
    (docs/architecture.md section 6)."""

    def full(q: np.ndarray) -> np.ndarray:
        out = np.repeat(params[None], len(q), axis=0)
        out[:, free] = q
        return out

    def difference(predicted: np.ndarray) -> np.ndarray:
        if not twist:
            return a - predicted
        out = np.zeros(predicted.shape[:-2] + (3, 4))
        out[..., :3, 0] = g.matrix_to_rotvec(a[..., :3, :3] @ np.swapaxes(predicted[..., :3, :3], -1, -2))
        out[..., :3, 3] = a[..., :3, 3] - predicted[..., :3, 3]
        return out

    def residuals_of(delta: np.ndarray, scale: np.ndarray) -> np.ndarray:
        whitened = delta[..., :3, :] / scale
        return whitened[..., :, [0, 3]].reshape(len(delta), -1) if twist else whitened.reshape(len(delta), -1)

    scale = _residual_scales(difference(batch(params[None])[0]), twist)
    for _ in range(_MAX_FITS):
        def residuals(q: np.ndarray, scale: np.ndarray = scale) -> np.ndarray:
            """Whitened residuals (K, M) of a batch of free parameters (K, F)."""
            p = full(q)
            return np.concatenate([residuals_of(difference(batch(p)), scale), p[:, priored] / prior], axis=1)

        result = least_squares(lambda q: residuals(q[None])[0], params[free], method="trf", x_scale="jac",
                               xtol=1e-10, ftol=1e-10, jac=lambda q: _forward_differences(residuals, q))
        params = full(result.x[None])[0]
        delta = difference(batch(params[None])[0])
        scale, previous = (_redundancy_scales(delta, result.jac) if twist else _residual_scales(delta)), scale
        if np.all(np.abs(scale / previous - 1.0) < _SCALES_SETTLED):
            break
    covariance = np.zeros((len(params), len(params)))
    covariance[np.ix_(free, free)] = np.linalg.pinv(result.jac.T @ result.jac)
    return params, covariance


def fit(testbed: TestbedConfig, c: ArmFitSettings, a: np.ndarray, r: Readings, fixtures: list[str],
        start: rwhe.Solution, compliant: bool) -> Fit:
    """Arms, ``Z``, ``X_f`` (and ``k_f``) from PnP poses ``a`` (N, 4, 4) and readings ``r``.

    Maximum a posteriori: the paper's Frobenius residuals divided by their scale and the
    parameters divided by their prior sigma; the covariance is ``(J^T J)^-1`` of those
    whitened residuals. Two scales, the RMS residual of the rotation entries and of the
    translation entries (m), as two variance components: one scale for both, as the
    paper's cost weighs them, took the translations (0.17 mm RMS on the default
    facility) as noisy as the rotations' 3e-4, which under-weighted them in the fit and
    widened the arms' covariance that reaches the labels' sigmas at 3-5 m
    (docs/accuracy.md, "The sigmas"). The scales start from ``start`` with nominal arms
    and are re-estimated from each fit until they settle."""
    names = sorted(start.x)
    sigma_prior = priors(c)
    world_up = np.asarray(c.world_up, float)

    def batch(p: np.ndarray) -> np.ndarray:
        return predict_batch(testbed, p, names, compliant, r, fixtures, world_up)

    params = np.concatenate([NOMINAL.params, rwhe.pack(start, names, compliant, anisotropic=compliant)])
    shape = rwhe.anisotropy_slice(names) if compliant else slice(0, 0)
    shape = slice(N_ARM + shape.start, N_ARM + shape.stop)
    # switched-off models stay at zero: they are not estimated, and carry no covariance
    free = np.ones(len(params), bool)
    free[ArmLayout.compliance] = c.joint_compliance == "on"
    free[shape] = c.fixture_anisotropy == "on"
    prior = np.concatenate([sigma_prior, np.full(shape.stop - shape.start, c.fixture_anisotropy_prior)])
    priored = np.concatenate([np.arange(N_ARM), np.arange(shape.start, shape.stop)])
    prior, priored = prior[free[priored]], priored[free[priored]]
    params, covariance = map_fit(batch, a, params, free, prior, priored)
    offsets = rwhe.unpack(params[N_ARM:], names, compliant, anisotropic=compliant)
    return Fit(offsets, ArmErrors(params[:N_ARM]), params, covariance, names, compliant)
