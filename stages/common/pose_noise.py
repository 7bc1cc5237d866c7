"""The covariance of the calibration poses' residuals that the arms' fit whitens by
(docs/architecture.md section 6, "the arms' fit").

A residual is the PnP pose against the arms' prediction: a small rotation applied on the
camera side (rad), then the translation (m), both in the camera frame, (6,) per pose. Two
things make it:

- the PnP pose's own error, whose covariance each pose's corners give
  (``observations.pnp_covariance``). It is far from diagonal: a board's sideways shift and
  its turn about the other sideways axis look alike through the lens (correlation 0.96 on
  TRON's board at 0.75 m), so most of a pose's sideways error is one combination of the two;
- what the arms' model leaves unexplained (the gearboxes, the thermal drift), independent
  between the axes as far as anything says: one variance for the rotations and one for the
  translations.

So pose ``i``'s covariance is ``S_i = v_pnp P_i + v_rot E_rot + v_t E_t`` (``E``: the
rotation's or the translation's identity block). The three variances are those that maximise
the restricted likelihood of the fit linearised where it stopped (REML: Patterson and
Thompson, Biometrika 58, 1971; Koch, *Parameter Estimation and Hypothesis Testing in Linear
Models*, 2nd ed., Springer 1999, section 3.6), by Fisher scoring in their logarithms. At that
maximum each component's whitened sum of squares equals its redundancy (Helmert's condition;
Foerstner, AVN 86, 1979), so a fit of many parameters to few poses does not take its small
residuals for small noise.

Without PnP covariances (poses from elsewhere, or ``calibrate.pose_weights = groups``)
``v_pnp`` is absent, and the two remaining components are each group's sum of squares over its
redundancy, in Helmert's closed form, one step per fit (``_Linearised.helmert``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_ROTATION = np.diag([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])
_TRANSLATION = np.diag([0.0, 0.0, 0.0, 1.0, 1.0, 1.0])
#: the range each variance may take, in units of the start's mean square of its group (the
#: PnP component: of its corners' own covariance): a component the data do not determine
#: would otherwise run to zero or to infinity along a flat likelihood
_BOUNDS = (1e-12, 1e6)
#: the most a Fisher step may change a variance's logarithm
_LARGEST_STEP = 2.0


@dataclass(frozen=True)
class ResidualCovariance:
    """The residual covariance of N calibration poses (the module's docstring)."""

    pnp: np.ndarray | None  # (N, 6, 6) each PnP pose's covariance; None: none known
    variances: np.ndarray  # (3,): v_pnp (unitless; 0 without ``pnp``), v_rot (rad^2), v_t (m^2)
    unit: np.ndarray  # (3,) what ``_BOUNDS`` are in units of

    @classmethod
    def start(cls, difference: np.ndarray, pnp: np.ndarray | None) -> ResidualCovariance:
        """The first guess from the start's residuals ``difference`` (N, 6): the PnP
        covariances at their own scale, and the rest of each group's mean square (at least
        a quarter of it) to the model."""
        rotation = max(float(np.mean(difference[:, :3] ** 2)), 1e-24)
        translation = max(float(np.mean(difference[:, 3:] ** 2)), 1e-24)
        unit = np.array([1.0, rotation, translation])
        if pnp is None:
            return cls(None, np.array([0.0, rotation, translation]), unit)
        pnp_rotation = float(np.mean(np.trace(pnp[:, :3, :3], axis1=1, axis2=2))) / 3
        pnp_translation = float(np.mean(np.trace(pnp[:, 3:, 3:], axis1=1, axis2=2))) / 3
        variances = np.array([1.0, max(rotation - pnp_rotation, 0.25 * rotation),
                              max(translation - pnp_translation, 0.25 * translation)])
        return cls(pnp, variances, unit)

    def components(self) -> list[np.ndarray]:
        """Each variance component's covariance shape, (N, 6, 6) or (6, 6)."""
        parts = [_ROTATION, _TRANSLATION]
        return parts if self.pnp is None else [self.pnp, *parts]

    def _variances(self) -> np.ndarray:
        return self.variances[1:] if self.pnp is None else self.variances

    def covariances(self, count: int) -> np.ndarray:
        """(N, 6, 6) each pose's residual covariance."""
        total = np.zeros((count, 6, 6))
        for variance, shape in zip(self._variances(), self.components(), strict=True):
            total = total + variance * np.broadcast_to(shape, (count, 6, 6))
        return total

    def whitening(self, count: int) -> np.ndarray:
        """(N, 6, 6) ``L_i^-1``, ``L_i`` the Cholesky factor of pose ``i``'s covariance: the
        whitened residual is ``L_i^-1`` times it."""
        return np.linalg.inv(np.linalg.cholesky(self.covariances(count)))

    def at_fit(self, fun: np.ndarray, jacobian: np.ndarray, count: int, tolerance: float = 1e-2,
               rounds: int = 50) -> ResidualCovariance:
        """The variances that maximise the restricted likelihood of the fit linearised where
        it stopped (REML, Patterson and Thompson 1971; at its maximum each component's
        whitened sum of squares equals its redundancy, Helmert's condition): its whitened
        residuals ``fun`` (M,) and Jacobian ``jacobian`` (M, F), whitened by this covariance
        (``whitening``), the first 6 N rows the ``count`` poses' (the rest: the priors', which
        no whitening touches).
        Fisher scoring in the variances' logarithms, halving a step that lowers the
        likelihood, until their square roots move by less than ``tolerance``: Helmert's
        own update, one component at a time, crept for hundreds of rounds where the PnP and
        the model's components overlap. Without PnP covariances, the two groups' variances
        in Helmert's closed form, one step (``_Linearised.helmert``)."""
        problem = _Linearised.of(fun, jacobian, np.linalg.cholesky(self.covariances(count)), count)
        if self.pnp is None:
            return ResidualCovariance(None, np.array([0.0, *problem.helmert(self._variances())]), self.unit)
        shapes = self.components()
        low, high = (np.log(bound * self.unit) for bound in _BOUNDS)
        theta = np.clip(np.log(np.maximum(self.variances, 1e-300)), low, high)
        likelihood, gradient, fisher = problem.evaluate(np.exp(theta), shapes)
        if not np.isfinite(likelihood):
            return self
        for _ in range(rounds):
            scale = np.exp(theta)
            step = np.linalg.lstsq(fisher * np.outer(scale, scale), gradient * scale, rcond=None)[0]
            step *= min(1.0, _LARGEST_STEP / max(float(np.max(np.abs(step))), 1e-300))
            for length in (1.0, 0.5, 0.25, 0.125, 0.0625):
                trial = np.clip(theta + length * step, low, high)
                tried = problem.evaluate(np.exp(trial), shapes)
                if np.isfinite(tried[0]) and tried[0] >= likelihood - 1e-9 * abs(likelihood):
                    break
            else:
                break  # no step raises the likelihood: at its maximum, as far as it can tell
            theta, (likelihood, gradient, fisher) = trial, tried
            if np.max(np.abs(step)) / 2 < tolerance:  # the full step, in the square roots' logarithms
                break
        return ResidualCovariance(self.pnp, np.exp(theta), self.unit)

    def settled(self, previous: ResidualCovariance, tolerance: float) -> bool:
        """Whether every variance's square root moved by less than ``tolerance`` (relative)."""
        now, before = self._variances(), previous._variances()
        return bool(np.all(np.abs(np.sqrt(now / before) - 1.0) < tolerance))


@dataclass(frozen=True)
class _Linearised:
    """The arms' fit linearised where it stopped, unwhitened: the poses' residuals (N, 6)
    and Jacobian (N, 6, F), and the priors' rows, already in their sigmas."""

    residual: np.ndarray
    jacobian: np.ndarray
    prior_residual: np.ndarray
    prior_jacobian: np.ndarray

    @classmethod
    def of(cls, fun: np.ndarray, jacobian: np.ndarray, factor: np.ndarray, count: int) -> _Linearised:
        """From the whitened ``fun`` and ``jacobian`` and the whitening's Cholesky ``factor`` (N, 6, 6)."""
        return cls(np.einsum("nij,nj->ni", factor, fun[:6 * count].reshape(count, 6)),
                   np.einsum("nij,njf->nif", factor, jacobian[:6 * count].reshape(count, 6, -1)),
                   fun[6 * count:], jacobian[6 * count:])

    def helmert(self, variances: np.ndarray) -> np.ndarray:
        """(2,) the rotations' (rad^2) and the translations' (m^2) variances, each group's sum of
        squares over its redundancy (Helmert's closed form, Foerstner 1979), the redundancy
        from the fit whitened by ``variances`` (2,): one step, not iterated to the restricted
        likelihood's maximum. Where the groups are the only components, the fits between the
        steps move the variances towards that maximum anyway, and iterating each step to it
        made the outer fits settle 8x slower (docs/accuracy.md, "the smoke profile keeps the two groups")."""
        count = len(self.residual)
        sigmas = np.sqrt(np.repeat(variances, 3))  # (6,)
        data = (self.jacobian / sigmas[None, :, None]).reshape(6 * count, -1)
        stacked = np.concatenate([data, self.prior_jacobian])
        leverage = np.einsum("ij,jk,ik->i", data, np.linalg.pinv(stacked.T @ stacked), data).reshape(count, 6)
        out = np.zeros(2)
        for group, columns in enumerate((slice(0, 3), slice(3, 6))):
            redundancy = max(3 * count - float(leverage[:, columns].sum()), 1.0)
            out[group] = max(float(np.sum(self.residual[:, columns] ** 2)) / redundancy, 1e-24)
        return out

    def evaluate(self, variances: np.ndarray, shapes: list[np.ndarray]) -> tuple[float, np.ndarray, np.ndarray]:
        """The restricted log-likelihood at ``variances`` (K,) of ``shapes`` (each (N, 6, 6)
        or (6, 6)), its gradient (K,) and Fisher information (K, K) by the variances:
        ``(e^T Q_k e - tr(R Q_k)) / 2`` and ``tr(R Q_k R Q_l) / 2``, ``Q_k`` whitened, ``R``
        the redundancy, all by blocks (Koch 1999, section 3.6)."""
        count = len(self.residual)
        whole = [np.broadcast_to(shape, (count, 6, 6)) for shape in shapes]
        try:
            cholesky = np.linalg.cholesky(sum(v * q for v, q in zip(variances, whole, strict=True)))
        except np.linalg.LinAlgError:
            return -np.inf, np.zeros(len(shapes)), np.zeros((len(shapes), len(shapes)))
        inverse = np.linalg.inv(cholesky)
        data = np.einsum("nij,njf->nif", inverse, self.jacobian)  # (N, 6, F)
        stacked = np.concatenate([data.reshape(6 * count, -1), self.prior_jacobian])
        observed = np.concatenate([np.einsum("nij,nj->ni", inverse, self.residual).ravel(), self.prior_residual])
        information = stacked.T @ stacked
        covariance = np.linalg.pinv(information)
        every = observed - stacked @ (covariance @ (stacked.T @ observed))  # the data's rows, then the priors'
        residual = every[:6 * count].reshape(count, 6)
        eigenvalues = np.linalg.eigvalsh(information)
        log_information = float(np.sum(np.log(eigenvalues[eigenvalues > 1e-12 * max(eigenvalues[-1], 1e-300)])))
        log_determinant = 2 * float(np.sum(np.log(np.abs(np.diagonal(cholesky, axis1=1, axis2=2)))))
        # -1/2 (log|S| + log|J^T S^-1 J| + e^T S^-1 e): the priors' rows belong to J and e, not to S;
        # a singular information counts its determined directions only (the pseudo-inverse's)
        likelihood = -0.5 * (log_determinant + log_information + float(np.sum(every**2)))
        whitened = [inverse @ q @ np.swapaxes(inverse, 1, 2) for q in whole]  # (N, 6, 6) each
        hat = (data @ covariance) @ np.swapaxes(data, 1, 2)  # the hat matrix's diagonal blocks
        flat = data.reshape(6 * count, -1)
        projected = [flat.T @ (q @ data).reshape(6 * count, -1) for q in whitened]  # J^T Q_k J
        size = len(shapes)
        gradient = np.zeros(size)
        fisher = np.zeros((size, size))
        for k in range(size):
            squares = float(np.einsum("ni,nij,nj->", residual, whitened[k], residual))
            gradient[k] = 0.5 * (squares - float(np.trace(whitened[k], axis1=1, axis2=2).sum()
                                                 - np.einsum("nij,nji->", hat, whitened[k])))
            for m in range(k, size):
                both = np.einsum("nij,njk->nik", whitened[k], whitened[m])
                trace = (float(np.trace(both, axis1=1, axis2=2).sum()) - 2 * float(np.einsum("nij,nji->", hat, both))
                         + float(np.sum((covariance @ projected[k]) * (covariance @ projected[m]).T)))
                fisher[k, m] = fisher[m, k] = 0.5 * trace
        return likelihood, gradient, fisher


def stacked_pnp(covariances: list[np.ndarray | None]) -> np.ndarray | None:
    """(N, 6, 6) the poses' PnP covariances, a pose without one given the others' mean;
    None where none has one."""
    known = [c for c in covariances if c is not None]
    if not known:
        return None
    mean = np.mean(known, axis=0)
    stacked = np.stack([mean if c is None else np.asarray(c, float) for c in covariances])
    return 0.5 * (stacked + np.swapaxes(stacked, 1, 2))  # exactly symmetric, as Cholesky needs
