"""What every arm model of calibrate and fuse shares (the model itself, built from each
robot's URDF: ``stages.common.robots.errors``; docs/architecture.md section 6): what the
target robot carries, the maximum a posteriori fit with its residuals' covariance, and a pose's
covariance from the fitted parameters and the joints' lost motion.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from stages.common import geometry as g
from stages.common import layout
from stages.common.pose_noise import ResidualCovariance
from stages.common.target import Target

#: mean square of a unit's lost motion over its rating's square: uniform on 50-100% of it
UNIT_SHARE = 7 / 12


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


def _forward_differences(function: Callable[[np.ndarray], np.ndarray], x: np.ndarray) -> np.ndarray:
    """The Jacobian (M, P) of a batched residual function ((K, P) -> (K, M)) at ``x`` (P,)
    by forward differences, with the steps of SciPy's ``2-point`` scheme (relative
    sqrt(eps), rounded to a representable difference), every step evaluated in one batch."""
    step = np.sqrt(np.finfo(float).eps) * np.where(x >= 0, 1.0, -1.0) * np.maximum(1.0, np.abs(x))
    batch = np.repeat(x[None], len(x) + 1, axis=0)
    batch[1 + np.arange(len(x)), np.arange(len(x))] = x + step
    values = function(batch)
    return ((values[1:] - values[0]) / ((x + step) - x)[:, None]).T


def pose_covariance_parts(jacobian: np.ndarray, parameters: np.ndarray,
                          joint_variance_rad2: np.ndarray | None = None,
                          joint_columns: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(N, 6, 6) twice (rotation applied on the camera side, rad; translation, m), from the
    poses' Jacobians (N, 6, P) by the fitted parameters (``identification.pose_jacobians``):
    the covariance from the parameters' covariance ``parameters`` (P, P), one draw shared by
    every capture of the session, which grows where the arms' configuration differs from
    the calibration's; and each capture's own, from the noise of its joint angles
    ``joint_variance_rad2`` (N, K) (``lost_motion.flank_variances``; zeros without),
    whose columns of the Jacobian are ``joint_columns`` (K,) (the joints' zero offsets)."""
    shared = jacobian @ parameters @ np.swapaxes(jacobian, -1, -2)
    own = np.zeros_like(shared)
    if joint_variance_rad2 is not None and joint_columns is not None:
        joints = jacobian[:, :, joint_columns]  # the camera's then the target's
        own = np.einsum("nij,nj,nkj->nik", joints, joint_variance_rad2, joints)
    return tuple(0.5 * (c + np.swapaxes(c, -1, -2)) for c in (shared, own))  # exactly symmetric despite rounding


#: the arms' fit stops re-estimating its residual variances when their square roots move by
#: less than this
_VARIANCES_SETTLED = 0.05
_MAX_FITS = 4
_TOLERANCE = 1e-8
#: the most iterations one fit takes (each a forward-difference Jacobian): a well-posed fit
#: converges in under 40 (TRON's default calibration: 24 at most), and one cross-validation
#: fold of a 3U CubeSat's smoke calibration, nearly degenerate, crept on for 4,587 to a cost
#: no lower than 33 reached (docs/development.md, Speed)
MAX_ITERATIONS = 300


@dataclass(frozen=True)
class MapFit:
    """The arms' fit: parameters (P,), their covariance (P, P), and the residuals'
    covariance it whitened by (``pose_noise``)."""

    params: np.ndarray
    covariance: np.ndarray
    noise: ResidualCovariance
    #: the last fit stopped at ``MAX_ITERATIONS`` evaluations before SciPy's tolerances were
    #: met: its parameters may be short of their optimum, and whoever reports the fit says so
    capped: bool


def pose_difference(a: np.ndarray, predicted: np.ndarray) -> np.ndarray:
    """(..., 6) PnP poses ``a`` against ``predicted`` (..., 4, 4): the rotation vector of
    the turn on the camera side (rad), then the translation (m)."""
    turn = g.matrix_to_rotvec(a[..., :3, :3] @ np.swapaxes(predicted[..., :3, :3], -1, -2))
    return np.concatenate([turn, a[..., :3, 3] - predicted[..., :3, 3]], axis=-1)


def map_fit(batch: Callable[[np.ndarray], np.ndarray], a: np.ndarray, params: np.ndarray, free: np.ndarray,
            prior: np.ndarray, priored: np.ndarray, pnp: np.ndarray | None = None) -> MapFit:
    """The maximum a posteriori parameters (P,) and their covariance (P, P) of any arms'
    model: ``batch`` predicts ``cam_from_target`` (K, N, 4, 4) of packed parameters (K, P),
    ``a`` (N, 4, 4) the PnP poses, ``pnp`` (N, 6, 6) their covariances (None: unknown),
    ``params`` (P,) the start, ``free`` (P,) bool the ones estimated (the rest stay as they
    start, with no covariance), ``prior`` the 1-sigma of the free parameters at indices
    ``priored`` (zero-mean priors). The residuals' variance components are re-estimated
    from each fit until they settle (below: why).

    The residuals are each pose's rotation vector (rad) and translation (m), not the paper's
    Frobenius entries: a rotation's nine matrix entries carry its three degrees of freedom,
    so weighing them as nine independent residuals takes three times the information they
    hold, and the covariance of a rotation-driven parameter comes out sqrt(3) too narrow.
    Each pose's residual is whitened by its covariance, the PnP pose's own plus the arms'
    model's (``pose_noise``): weighed as independent rotations and translations, the PnP
    poses' sideways shifts, which are one with their turns, counted twice (docs/accuracy.md,
    "the PnP poses' own covariance"). The variances are
    estimated from the residuals' redundancy (Helmert's variance components: the trace of
    each component's share of the hat matrix's complement): a model of many parameters
    fitted to few poses leaves residuals smaller than the noise, and a scale taken from
    them alone would weigh the data ever higher, fit after fit (docs/architecture.md
    section 6)."""
    from scipy.optimize import least_squares

    def full(q: np.ndarray) -> np.ndarray:
        out = np.repeat(params[None], len(q), axis=0)
        out[:, free] = q
        return out

    noise = ResidualCovariance.start(pose_difference(a, batch(params[None])[0]), pnp)
    for _ in range(_MAX_FITS):
        whitening = noise.whitening(len(a))

        def residuals(q: np.ndarray, whitening: np.ndarray = whitening) -> np.ndarray:
            """Whitened residuals (K, M) of a batch of free parameters (K, F)."""
            p = full(q)
            whitened = np.einsum("nij,knj->kni", whitening, pose_difference(a, batch(p)))
            return np.concatenate([whitened.reshape(len(q), -1), p[:, priored] / prior], axis=1)

        # SciPy's default tolerances (1e-8): 1e-10 spent 4x the iterations creeping along the
        # weakly determined directions, moving the parameters by under 0.002 of their sigma
        # (docs/development.md, Speed)
        result = least_squares(lambda q: residuals(q[None])[0], params[free], method="trf", x_scale="jac",
                               xtol=_TOLERANCE, ftol=_TOLERANCE, max_nfev=MAX_ITERATIONS,
                               jac=lambda q: _forward_differences(residuals, q))
        params = full(result.x[None])[0]
        noise, previous = noise.at_fit(result.fun, result.jac, len(a)), noise
        if noise.settled(previous, _VARIANCES_SETTLED):
            break
    covariance = np.zeros((len(params), len(params)))
    covariance[np.ix_(free, free)] = np.linalg.pinv(result.jac.T @ result.jac)
    return MapFit(params, covariance, previous, bool(result.status == 0))  # 0: max_nfev reached
