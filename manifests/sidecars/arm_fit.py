"""The arms' identified kinematics in ``W/calibration.json`` (each source's
``arm_kinematics``, when calibrate estimated them): the facility's robots from their URDFs
(``ChainFit``: ``stages.common.robots.errors`` gives the model; TRON's KR 16-2 pair is the
built-in facility's), with the fixtures and compliance they were fitted with and the
packed parameters with their covariance, which fuse propagates to each capture's
configuration."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from manifests.sidecars.base import Fields, SidecarError


@dataclass(frozen=True)
class RobotCorrection:
    """One facility robot's identified errors (``stages/common/robots/errors.py`` gives the
    model): the encoders' zero offsets (J,) rad (m for a prismatic joint), in its URDF's
    joint order; each origin's frame error (J + 1, 6), a rotation vector (rad) then a
    translation (m) in that origin's frame, the last the flange's; the rail's scale error
    (None without a rail); each joint's compliance (J,) rad/(N m) and lost motion (J,) rad
    (gearbox backlash plus hysteresis; 0 where not fitted)."""

    robot: str
    role: str  # "camera" or "target": what it carries
    joints: tuple[str, ...]
    zero_offsets: tuple[float, ...]
    frame_errors: tuple[tuple[float, ...], ...]
    rail_scale_error: float | None
    compliance_rad_per_nm: tuple[float, ...]
    lost_motion_rad: tuple[float, ...]

    def to_json(self) -> dict[str, Any]:
        return {"robot": self.robot, "role": self.role, "joints": list(self.joints),
                "zero_offsets": list(self.zero_offsets), "frame_errors": [list(row) for row in self.frame_errors],
                "rail_scale_error": self.rail_scale_error, "compliance_rad_per_nm": list(self.compliance_rad_per_nm),
                "lost_motion_rad": list(self.lost_motion_rad)}

    @classmethod
    def from_fields(cls, f: Fields) -> RobotCorrection:
        f.only("robot", "role", "joints", "zero_offsets", "frame_errors", "rail_scale_error", "compliance_rad_per_nm",
               "lost_motion_rad")
        joints = f.raw("joints")
        if not isinstance(joints, list) or not joints or not all(isinstance(n, str) for n in joints):
            raise f.fail("joints", "a list of joint names")
        count = len(joints)
        rail = None if f.raw("rail_scale_error") is None else f.number("rail_scale_error")
        return cls(f.text("robot"), f.text("role", ("camera", "target")), tuple(joints),
                   f.vector("zero_offsets", count), f.matrix("frame_errors", count + 1, 6), rail,
                   f.vector("compliance_rad_per_nm", count), f.vector("lost_motion_rad", count))


@dataclass(frozen=True)
class ResidualNoise:
    """What the arms' fit whitened its calibration poses by (``stages/common/pose_noise.py``):
    the factor on each PnP pose's own covariance (a variance) from its corners, and the
    1-sigma per axis of what the arms' model leaves unexplained in a pose: its rotation (rad)
    and its translation (m). Where the poses were weighed as two groups
    (``calibrate.pose_weights = groups``) ``pnp_scale`` is None and the two 1-sigmas hold the
    PnP poses' own error too. Each variance is its sum of squares over its redundancy, not
    the residuals' plain spread, which a fit of many parameters shrinks."""

    pnp_scale: float | None
    rotation_sigma_rad: float
    translation_sigma_m: float

    def to_json(self) -> dict[str, Any]:
        return {"pnp_scale": self.pnp_scale, "rotation_sigma_rad": self.rotation_sigma_rad,
                "translation_sigma_m": self.translation_sigma_m}

    @classmethod
    def from_fields(cls, f: Fields) -> ResidualNoise:
        f.only("pnp_scale", "rotation_sigma_rad", "translation_sigma_m")
        scale = None if f.raw("pnp_scale") is None else f.number("pnp_scale", positive=True)
        values = [f.number(key) for key in ("rotation_sigma_rad", "translation_sigma_m")]
        for key, value in zip(("rotation_sigma_rad", "translation_sigma_m"), values, strict=True):
            if value < 0:
                raise f.fail(key, "a 1-sigma >= 0")
        return cls(scale, *values)


def _names(f: Fields, key: str) -> tuple[str, ...]:
    names = f.raw(key)
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise f.fail(key, "a list of names")
    return tuple(names)


def _numbers(f: Fields, key: str) -> dict[str, float]:
    entry = f.child(key)
    return {name: entry.number(name) for name in entry.data}


@dataclass(frozen=True)
class ChainFit:
    """A facility's robots fitted from their URDFs (``stages/common/robots/identification.py``):
    each robot's corrections; the arms' parameter names in the packed order; those dropped
    as inseparable, each with what absorbs it; the kept ones the calibration poses leave
    weakly determined (posterior over prior 1-sigma); the fixtures of the offsets, whether
    they were compliant; the packed parameters (P,) (the arms', then the offsets') with
    their covariance (P, P); the arms' prior 1-sigmas; the gravity torque (N m) above which
    a joint was taken to rest on its loaded flank (``calibrate.backlash_preload_nm``), which
    fuse must take the same; and what the fit whitened the poses by (``ResidualNoise``)."""

    robots: tuple[RobotCorrection, ...]
    parameter_names: tuple[str, ...]
    dropped: dict[str, str]
    weak: dict[str, float]
    fixtures: tuple[str, ...]
    compliant: bool
    parameters: tuple[float, ...]
    covariance: tuple[tuple[float, ...], ...]
    prior_sigma: tuple[float, ...]
    backlash_preload_nm: float
    residual_noise: ResidualNoise

    def to_json(self) -> dict[str, Any]:
        return {"robots": [robot.to_json() for robot in self.robots], "parameter_names": list(self.parameter_names),
                "dropped": dict(self.dropped), "weak": dict(self.weak), "fixtures": list(self.fixtures),
                "compliant": self.compliant, "parameters": list(self.parameters),
                "covariance": [list(row) for row in self.covariance], "prior_sigma": list(self.prior_sigma),
                "backlash_preload_nm": self.backlash_preload_nm, "residual_noise": self.residual_noise.to_json()}

    @classmethod
    def from_fields(cls, f: Fields) -> ChainFit:
        f.only("robots", "parameter_names", "dropped", "weak", "fixtures", "compliant", "parameters", "covariance",
               "prior_sigma", "backlash_preload_nm", "residual_noise")
        robots = f.raw("robots")
        if not isinstance(robots, list) or not robots:
            raise f.fail("robots", "a list of robot corrections")
        parameters = f.vector("parameters")
        names = _names(f, "parameter_names")
        dropped = f.child("dropped")
        if not all(isinstance(robot, dict) for robot in robots):
            raise f.fail("robots", "a list of objects")
        entries = tuple(Fields(robot, f.where, f"{f.key('robots')}[{i}].") for i, robot in enumerate(robots))
        corrections = tuple(RobotCorrection.from_fields(entry) for entry in entries)
        roles = [robot.role for robot in corrections]
        if len(set(roles)) != len(roles):
            raise f.fail("robots", "one correction per role (camera, target)")
        # each robot packs J zero offsets, J + 1 frame errors of 6, its rail's scale, J compliances, J lost motions
        size = sum(len(r.joints) * 9 + 6 + (r.rail_scale_error is not None) for r in corrections)
        if len(names) != size:
            raise f.fail("parameter_names", f"{size} names, as the robots' joints and rails pack them")
        if len(parameters) < size:
            raise f.fail("parameters", f"at least the robots' {size} parameters, then the offsets'")
        weak = _numbers(f, "weak")
        unknown = sorted((set(dropped.data) | set(weak)) - set(names))
        if unknown:
            raise SidecarError(f"{f.where}: keys {f.key('dropped')} and {f.key('weak')}: {unknown[0]!r} is not one "
                               "of parameter_names")
        return cls(corrections, names, {name: dropped.text(name) for name in dropped.data}, weak,
                   _names(f, "fixtures"), f.boolean("compliant"), parameters,
                   f.matrix("covariance", len(parameters), len(parameters)), f.vector("prior_sigma", len(names)),
                   f.number("backlash_preload_nm"), ResidualNoise.from_fields(f.child("residual_noise")))
