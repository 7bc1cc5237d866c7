"""The arms' model calibrate fits with the hand-eye offsets: the facility's robots, each
from its URDF (``stages.common.robots.identification``; TRON's KR 16-2 pair is the built-in
facility's, core/facilities/tron), behind one small interface: read the captures'
readings, fit, correct ``B``, and record."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from core import progress
from core.config import Config
from manifests.sidecars import ArmKinematics
from stages.common import arms, rwhe
from stages.common.robots import identification
from stages.common.robots.errors import Holders, configured_holders

#: a session's encoder readings
Readings = identification.Measured


@dataclass(frozen=True)
class Fitted:
    """The arms and offsets fitted together."""

    offsets: rwhe.Solution
    model: ArmsModel
    fit: identification.Fitted

    def corrected_b(self, r: Readings) -> tuple[np.ndarray, np.ndarray]:
        """``B`` (N, 4, 4) and the up direction in the target flange (N, 3) of readings ``r``."""
        return self.model.corrected_b(self.fit, r)

    def up_before(self, r: Readings) -> np.ndarray:
        """(N, 3) the up direction in the target flange at each capture's one before (NaN:
        none), for ``offsets.predict``'s fixture play."""
        return self.fit.up_before(r, np.asarray(self.model.settings.world_up, float))

    def kinematics(self, note: str) -> ArmKinematics:
        return self.model.kinematics(self.fit, note)

    def offsets_covariance(self) -> np.ndarray:
        """(Q, Q) the fit's covariance of the offsets' packed parameters (``rwhe.pack``),
        marginal over the arms'."""
        arms_size = self.model.size
        return np.asarray(self.fit.covariance)[arms_size:, arms_size:]


@dataclass(frozen=True)
class ArmsModel:
    """A facility's robots, each from its URDF; ``settings``: the calibrate section."""

    settings: Any
    payload: arms.Payload
    holders: Holders
    name: str  # how the notes call the robots

    @property
    def size(self) -> int:
        """How many of the packed parameters are the arms' (the offsets follow)."""
        return self.holders.size

    def readings(self, rows: list[dict[str, Any]]) -> Readings | None:
        """The readings of capture ``rows`` (with ``identification.move_directions``' keys where
        the session's order of moves is known)."""
        return identification.measured(self.holders, rows, self.payload, np.asarray(self.settings.world_up),
                                       self.settings.backlash_preload_nm)

    def fit(self, a: np.ndarray, r: Readings, fixtures: list[str], start: rwhe.Solution,
            compliant: bool, pnp: np.ndarray | None = None,
            verdicts: identification.Verdicts | None = None) -> Fitted:
        """The arms and offsets from PnP poses ``a`` (N, 4, 4) of covariances ``pnp``
        (N, 6, 6; None: unknown, ``pose_noise.stacked_pnp``); ``verdicts``: the whole
        calibration's, which a cross-validation fold takes (``identification.Verdicts``)."""
        fitted = identification.fit(self.holders, self.settings, a, r, start, compliant, self.payload, pnp,
                                    verdicts)
        return Fitted(fitted.offsets, self, fitted)

    def corrected_b(self, fit: identification.Fitted, r: Readings) -> tuple[np.ndarray, np.ndarray]:
        return fit.corrected_b(r, np.asarray(self.settings.world_up, float))

    def parameters(self, fixtures: list[str], compliant: bool) -> int:
        """How many parameters the fit would estimate on samples of ``fixtures``: the arms'
        identifiable ones and the offsets."""
        return identification.fitted_parameter_count(self.holders, self.settings, fixtures, compliant, self.payload,
                                                     np.asarray(self.settings.world_up, float))

    def kinematics(self, fit: identification.Fitted, note: str) -> ArmKinematics:
        record = fit.record()
        kept = len(record.parameter_names) - len(record.dropped)
        if fit.capped:
            capped = (f"the arms' fit stopped at its cap of {arms.MAX_ITERATIONS} evaluations before converging: "
                      "the poses barely determine some direction of the parameters (chains.weak), and the "
                      "fit may be short of its optimum there")
            progress.note(f"calibrate: {self.name}: {capped}")
            note = f"{note}; {capped}"
        progress.note(f"calibrate: {self.name}: {kept} of {len(record.parameter_names)} parameters identifiable; "
                      f"{len(record.weak)} weakly determined by these poses"
                      + (f" (weakest: {_weakest(record.weak)})" if record.weak else ""))
        return ArmKinematics(True, f"{note}; {kept} of {len(record.parameter_names)} parameters identifiable, "
                             f"{len(record.dropped)} held at zero (named in chains.dropped, with why)", record)


def _weakest(weak: dict[str, float]) -> str:
    chosen = sorted(weak.items(), key=lambda item: -item[1])[:3]
    return ", ".join(f"{name} +-{ratio:.0%} of its prior" for name, ratio in chosen)


def facility_decision(config: Config, model: ArmsModel, count: int, fixtures: list[str],
                      compliant: bool) -> tuple[bool, str] | None:
    """Under ``calibrate.arm_kinematics = auto``, a facility folder's arms are fitted only
    where the captures give ``calibrate.min_arm_redundancy`` equations (six a capture) per
    parameter: fewer, and the many parameters of two URDF arms fit the calibration poses'
    noise and carry it to the dataset's (issue 57's smoke rehearsals: the robots' labels
    erred 6.0 and 10.9 mm fitted from 15 captures against 5.1 and 7.4 mm left nominal).
    TRON's own KR 16-2 pair is fitted from any count, as it always was: fitted from the
    smoke profile's 16 captures, facilities 11 and 33 labelled to 3.3 and 6.5 mm against
    10.6 and 10.8 mm with the arms left nominal (docs/accuracy.md). None: no objection."""
    if not config.facility.path or config.calibrate.arm_kinematics != "auto":
        return None
    parameters = model.parameters(fixtures, compliant)
    needed = config.calibrate.min_arm_redundancy * parameters / 6
    if count >= needed:
        return None
    return False, (f"{count} calibration captures give {6 * count} equations for the {parameters} parameters of "
                   f"{model.name} and the offsets, under calibrate.min_arm_redundancy = "
                   f"{config.calibrate.min_arm_redundancy:g} per parameter ({int(np.ceil(needed))} captures): "
                   "the arms are left at their URDFs (plan.n_calibration; or set calibrate.arm_kinematics = on)")


def arms_model(config: Config, payload: arms.Payload) -> ArmsModel:
    """The model of the configured facility's arms (TRON's: the built-in folder's, placed by ``[testbed]``)."""
    holders, facility = configured_holders(config.facility.path, config.testbed)
    names = " and ".join(robot.robot for robot in holders.robots)
    return ArmsModel(config.calibrate, payload, holders, f"{facility.spec.name}'s {names}")
