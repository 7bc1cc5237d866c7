"""The arms' model calibrate fits with the hand-eye offsets: TRON's KR 16-2 pair
(``stages.common.arms``) or a facility folder's robots from their URDFs
(``stages.common.robots.identification``), behind one small interface: read the captures'
readings, fit, correct ``B``, and record."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from core import progress
from core.config import Config, TestbedConfig
from manifests.sidecars import ArmKinematics
from stages.common import arms, rwhe
from stages.common.robots import identification
from stages.common.robots.errors import Holders
from stages.common.robots.facility import load_facility


class Readings(Protocol):
    """A session's encoder readings (``arms.Readings`` or ``identification.Measured``)."""

    def subset(self, mask: np.ndarray) -> Readings: ...


@dataclass(frozen=True)
class Fitted:
    """The arms and offsets fitted together."""

    offsets: rwhe.Solution
    model: ArmsModel
    fit: Any  # arms.Fit or identification.Fitted

    def corrected_b(self, r: Readings) -> tuple[np.ndarray, np.ndarray]:
        """``B`` (N, 4, 4) and the up direction in the target flange (N, 3) of readings ``r``."""
        return self.model.corrected_b(self.fit, r)

    def kinematics(self, note: str) -> ArmKinematics:
        return self.model.kinematics(self.fit, note)

    def offsets_covariance(self) -> np.ndarray:
        """(Q, Q) the fit's covariance of the offsets' packed parameters (``rwhe.pack``),
        marginal over the arms'."""
        arms_size = self.model.size
        return np.asarray(self.fit.covariance)[arms_size:, arms_size:]


class ArmsModel(Protocol):
    name: str  # how Table 1 and the notes call the robots

    @property
    def size(self) -> int:
        """How many of the packed parameters are the arms' (the offsets follow)."""

    def readings(self, rows: list[dict[str, Any]]) -> Readings | None: ...

    def fit(self, a: np.ndarray, r: Readings, fixtures: list[str], start: rwhe.Solution,
            compliant: bool) -> Fitted: ...

    def corrected_b(self, fit: Any, r: Readings) -> tuple[np.ndarray, np.ndarray]: ...

    def kinematics(self, fit: Any, note: str) -> ArmKinematics: ...


@dataclass(frozen=True)
class KukaArms:
    """TRON's two KR 16-2 arms (the configuration's ``[testbed]``); ``settings``: the
    calibrate section."""

    testbed: TestbedConfig
    settings: Any
    payload: arms.Payload
    name: str = "TRON's KR 16-2 arms"

    @property
    def size(self) -> int:
        return arms.N_ARM

    def readings(self, rows: list[dict[str, Any]]) -> arms.Readings | None:
        return arms.readings(rows, self.payload)

    def fit(self, a: np.ndarray, r: arms.Readings, fixtures: list[str], start: rwhe.Solution,
            compliant: bool) -> Fitted:
        fitted = arms.fit(self.testbed, self.settings, a, r, fixtures, start, compliant)
        return Fitted(fitted.offsets, self, fitted)

    def corrected_b(self, fit: arms.Fit, r: arms.Readings) -> tuple[np.ndarray, np.ndarray]:
        return arms.corrected_b(self.testbed, fit.errors, r, self.settings.world_up)

    def kinematics(self, fit: arms.Fit, note: str) -> ArmKinematics:
        return ArmKinematics(True, note, fit.record())


@dataclass(frozen=True)
class FacilityArms:
    """A facility folder's robots, each from its URDF; ``settings``: the calibrate section."""

    settings: Any
    payload: arms.Payload
    holders: Holders
    name: str

    @property
    def size(self) -> int:
        return self.holders.size

    def readings(self, rows: list[dict[str, Any]]) -> identification.Measured | None:
        return identification.measured(self.holders, rows, self.payload, np.asarray(self.settings.world_up))

    def fit(self, a: np.ndarray, r: identification.Measured, fixtures: list[str], start: rwhe.Solution,
            compliant: bool) -> Fitted:
        fitted = identification.fit(self.holders, self.settings, a, r, start, compliant, self.payload)
        return Fitted(fitted.offsets, self, fitted)

    def corrected_b(self, fit: identification.Fitted, r: identification.Measured) -> tuple[np.ndarray, np.ndarray]:
        return fit.corrected_b(r, np.asarray(self.settings.world_up, float))

    def parameters(self, fixtures: list[str], compliant: bool) -> int:
        """How many parameters the fit would estimate on samples of ``fixtures``: the arms'
        identifiable ones and the offsets."""
        return identification.fitted_parameter_count(self.holders, self.settings, fixtures, compliant, self.payload,
                                                     np.asarray(self.settings.world_up, float))

    def kinematics(self, fit: identification.Fitted, note: str) -> ArmKinematics:
        record = fit.record()
        kept = len(record.parameter_names) - len(record.dropped)
        progress.note(f"calibrate: {self.name}: {kept} of {len(record.parameter_names)} parameters identifiable; "
                      f"{len(record.weak)} weakly determined by these poses"
                      + (f" (weakest: {_weakest(record.weak)})" if record.weak else ""))
        return ArmKinematics(True, f"{note}; {kept} of {len(record.parameter_names)} parameters identifiable, "
                             f"{len(record.dropped)} dropped as inseparable (named in chains.dropped)", None, record)


def _weakest(weak: dict[str, float]) -> str:
    chosen = sorted(weak.items(), key=lambda item: -item[1])[:3]
    return ", ".join(f"{name} +-{ratio:.0%} of its prior" for name, ratio in chosen)


def facility_decision(config: Config, model: ArmsModel, count: int, fixtures: list[str],
                      compliant: bool) -> tuple[bool, str] | None:
    """Under ``calibrate.arm_kinematics = auto``, a facility's arms are fitted only where
    the captures give ``calibrate.min_arm_redundancy`` equations (six a capture) per
    parameter: fewer, and the many parameters of two URDF arms fit the calibration poses'
    noise and carry it to the dataset's (issue 57's smoke rehearsals: the robots' labels
    erred 6.0 and 10.9 mm fitted from 15 captures against 5.1 and 7.4 mm left nominal).
    None: no objection."""
    if not isinstance(model, FacilityArms) or config.calibrate.arm_kinematics != "auto":
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
    """The model of the configured facility's arms."""
    if not config.facility.path:
        return KukaArms(config.testbed, config.calibrate, payload)
    facility = load_facility(Path(config.facility.path))
    holders = Holders.of(facility)
    names = " and ".join(robot.robot for robot in holders.robots)
    return FacilityArms(config.calibrate, payload, holders, f"{facility.spec.name}'s {names}")
