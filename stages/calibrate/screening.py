"""Screen the calibration captures between PnP and the solve: an estimated camera must fit
the images, patterns are seen from the front, every chessboard's corners are put in one
order, single images that disagree with the robot's motion are rejected (each with its
reason), and the whole set is refused, naming the likely cause, when the detections do
not fit the declared pattern (``stages.calibrate.consistency``); after the solve, absurd
results are refused. Thresholds: ``CalibrateConfig``; why: docs/accuracy.md.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from manifests.sidecars import Folds
from stages.calibrate import observations as obs
from stages.calibrate.config import CalibrateConfig
from stages.calibrate.consistency import Pairs, choose_orderings, robust_flags, rotation_fit
from stages.common import geometry as g
from stages.common.patterns import PatternSpec
from stages.common.rwhe import DegenerateError


class InconsistentPatternError(DegenerateError):
    """The detections do not fit the declared pattern and the robot; the message names why."""


def named(sample_ids: list[str], most: int = 6) -> str:
    """A short list of samples for a message (their files: captures.source_image)."""
    more = f" and {len(sample_ids) - most} more" if len(sample_ids) > most else ""
    return ", ".join(sample_ids[:most]) + more


def likely_causes(observations: list[obs.Observation], spec: PatternSpec) -> list[str]:
    """What the images themselves say about a pattern definition that does not fit them."""
    causes = []
    checked = [o for o in observations if "board_continues" in o.extra]
    larger = [o for o in checked if o.extra["board_continues"]]
    if checked and len(larger) >= max(1, len(checked) // 3):
        sides = sorted({side for o in larger for side in o.extra["board_continues"]})
        causes.append(f"the printed chessboard is larger than [pattern] size = {list(spec.size)} inner corners: its "
                      f"squares go on beyond the detected grid ({', '.join(sides)}) in {len(larger)} of "
                      f"{len(checked)} images ({named([o.sample_id for o in larger])}), so each image may show "
                      "another part of it; count the inner corners (squares minus one) along each side")
    return causes


def check_facing(observations: list[obs.Observation], spec: PatternSpec) -> dict[str, Any]:
    """A pattern is seen from its front: its z axis (into the board) points away from the
    camera. A PnP pose from behind means the corners were labelled in mirror image (an
    image flipped by a camera driver, a mirrored ordering): rejected, or, when most
    images are, the set is refused."""
    target_from_pattern = g.transform_from_qt(spec.target_from_pattern_q, spec.target_from_pattern_t)
    posed = [o for o in observations if o.cam_from_target is not None]
    behind = []
    for o in posed:
        cam_from_pattern = o.cam_from_target @ target_from_pattern
        if cam_from_pattern[:3, 2] @ cam_from_pattern[:3, 3] <= 0:
            behind.append(o)
    if posed and len(behind) > 0.5 * len(posed):
        _refuse(f"the pattern is seen from behind in {len(behind)} of {len(posed)} images "
                f"({named([o.sample_id for o in behind])})", observations, spec,
                ["mirrored images (a camera driver's flip) or a mirrored corner ordering"])
    for o in behind:
        o.reason, o.cam_from_target = ("the pattern is seen from behind: its corners are labelled in mirror image "
                                       "(a flipped image?)"), None
    return {"mirrored": [o.sample_id for o in behind]}


def _refuse(message: str, observations: list[obs.Observation], spec: PatternSpec, extra: list[str]) -> None:
    causes = likely_causes(observations, spec) + extra
    hint = "; likely cause: " + "; or ".join(causes) if causes else ""
    raise InconsistentPatternError(f"calibration refused: {message}{hint}")


def check_intrinsics(intrinsics: obs.EstimatedCamera, observations: list[obs.Observation], spec: PatternSpec,
                     limits: CalibrateConfig) -> None:
    """An estimated camera must fit most images, and fit them well."""
    detected = [o for o in observations if len(o.ids) >= limits.min_corners]
    kept = [o for o in detected if o.reason is None]
    if intrinsics.rms_px > limits.max_intrinsics_rms_px or len(kept) < 0.5 * len(detected):
        misfits = [o.sample_id for o in detected if o.reason is not None]
        _refuse(f"the camera model fits {len(kept)} of {len(detected)} images with the pattern (not "
                f"{named(misfits) or 'any'}), with a reprojection "
                f"RMS of {intrinsics.rms_px:.3g} px (at most {limits.max_intrinsics_rms_px:g} px expected: "
                "corners of one printed pattern fit a camera to a fraction of a pixel)", observations, spec,
                ["a [pattern] size, square_m or kind that does not match the printed board"])


def order_corners(observations: list[obs.Observation], b: dict[str, np.ndarray], fixtures: dict[str, str],
                  spec: PatternSpec, intrinsics: obs.EstimatedCamera, limits: CalibrateConfig) -> dict[str, Any]:
    """Relabel chessboards found from their other end so that every image agrees with the
    robot's motion; an image whose order cannot be decided is rejected with its reason."""
    reorderings = spec.reorderings()
    used = [o for o in observations if o.cam_from_target is not None]
    if not reorderings or len(used) < 3:
        return {"reordered": [], "undecided": []}
    options: list[list[np.ndarray | None]] = []
    for o in used:
        poses: list[np.ndarray | None] = [o.cam_from_target]
        for _, mapping in reorderings:
            trial = obs.Observation(o.sample_id, mapping[o.ids], o.pixels, np.zeros((0, 3)))
            obs.relabel(trial, spec, mapping[o.ids])
            obs.pnp(trial, intrinsics)
            poses.append(trial.cam_from_target)
        options.append(poses)
    labels, margins = choose_orderings(options, np.stack([b[o.sample_id] for o in used]),
                                       [fixtures[o.sample_id] for o in used])
    reordered, undecided = [], []
    for o, label, margin in zip(used, labels, margins, strict=True):
        if margin < limits.motion_angle_floor_rad:
            undecided.append(o.sample_id)
            o.reason, o.cam_from_target = (f"chessboard corner order cannot be decided: the robot's motion fits "
                                           f"two orders within {np.degrees(margin):.2f} deg"), None
        elif label:
            name, mapping = reorderings[label - 1]
            obs.relabel(o, spec, mapping[o.ids])
            obs.pnp(o, intrinsics)
            o.extra["reordered"] = name
            reordered.append(o.sample_id)
    return {"reordered": reordered, "undecided": undecided}


def check_motions(observations: list[obs.Observation], b: dict[str, np.ndarray], fixtures: dict[str, str],
                  spec: PatternSpec, limits: CalibrateConfig, length_hint: str) -> dict[str, Any]:
    """Screw congruence of the camera's and the robot's motions: reject single images that
    disagree, refuse the set when most do, when the pitches differ by a scale, or when the
    robot's poses fit only inverted."""
    used = [o for o in observations if o.cam_from_target is not None]
    if len(used) < 3:
        return {"checked": len(used)}
    a = np.stack([o.cam_from_target for o in used])
    b_used = np.stack([b[o.sample_id] for o in used])
    names = [fixtures[o.sample_id] for o in used]
    pairs = Pairs.of(a, b_used, names)
    angle, pitch = pairs.angle_scores(), pairs.pitch_scores()
    straight = rotation_fit(a, b_used, names)
    inverted = rotation_fit(a, np.stack([g.invert(m) for m in b_used]), names)
    if straight > limits.motion_angle_floor_rad and inverted < 0.25 * straight:
        _refuse(f"the robot's poses fit the camera's motion only inverted (one camera-side rotation maps the "
                f"robot's turns onto the camera's to {np.degrees(straight):.2f} deg as given, "
                f"{np.degrees(inverted):.3f} deg inverted)", [], spec,
                ["the pose file's transform is the other way round (base_from_flange or flange_from_base), or "
                 "the camera is on the other side ([setup] camera_on flange or world)"])
    angle_bad, angle_limit = robust_flags(angle, limits.motion_angle_floor_rad, limits.outlier_k)
    scale, spread, scale_se = pairs.scale(~angle_bad)
    # beyond the limit by more than its noise: a wrong square size or unit scales every
    # motion alike, where arms that err by millimetres only blur the ratio
    if scale is not None and abs(scale - 1.0) - 2.0 * scale_se > limits.max_scale_error:
        _refuse(f"the camera's motions are {scale:.3f} (+- {scale_se:.3f}) times the robot's along their screw axes "
                f"({spread * 1000:.0f} mm RMS robot pitch)", observations, spec,
                [f"[pattern] square_m = {spec.square_m:g} m, but the images suggest {spec.square_m / scale:.4g} m "
                 "(a printer's scaling?)", f"robot lengths in another unit than {length_hint}"])
    pitch_bad, pitch_limit = robust_flags(pitch, limits.motion_pitch_floor_m, limits.outlier_k)
    travel = pairs.travel_scores()
    travel_bad, travel_limit = robust_flags(travel, limits.motion_pitch_floor_m, limits.outlier_k)
    bad = angle_bad | pitch_bad | travel_bad
    if bad.sum() > 0.5 * len(used):
        flagged = [o.sample_id for o, flag in zip(used, bad, strict=True) if flag]
        _refuse(f"{len(flagged)} of {len(used)} images ({named(flagged)}) disagree with the robot's motion "
                f"(median rotation-angle mismatch {np.degrees(np.nanmedian(angle)):.2f} deg, pitch mismatch "
                f"{1000 * np.nanmedian(pitch):.1f} mm)", observations, spec,
                ["images and poses paired in another order (the N-th image must belong to the N-th pose)",
                 "a chessboard whose corner order flips or mirrors between images"])
    for o, a_score, p_score, t_score, flag in zip(used, angle, pitch, travel, bad, strict=True):
        if flag:
            still = "" if not np.isfinite(t_score) else (f", travels without turning by {1000 * t_score:.1f} mm "
                                                         f"(limit {1000 * travel_limit:.1f})")
            o.reason = (f"disagrees with the robot's motion: rotation angles differ by {np.degrees(a_score):.2f} deg "
                        f"(limit {np.degrees(angle_limit):.2f}), pitches by {1000 * p_score:.1f} mm (limit "
                        f"{1000 * pitch_limit:.1f}){still}, median over its pairs")
            o.cam_from_target = None
    return {"checked": len(used), "rejected": [o.sample_id for o, flag in zip(used, bad, strict=True) if flag],
            "rotation_fit_rad": straight, "rotation_fit_inverted_rad": inverted,
            "angle_mismatch_rad_median": float(np.nanmedian(angle)),
            "pitch_mismatch_m_median": float(np.nanmedian(pitch)),
            "pitch_scale": scale, "pitch_scale_se": None if scale is None else scale_se,
            "angle_limit_rad": angle_limit, "pitch_limit_m": pitch_limit, "travel_limit_m": travel_limit}


#: what a recording's refusal advises: where a lab's files go wrong
INLIER_ADVICE = ("check the pose file's transform and units, [setup] camera_on, and the pairing of images and "
                 "poses")
RESULT_ADVICE = ("check the pose file's units and transform, the pairing of images and poses, and the [pattern] "
                 "definition")
#: what a virtual run's refusal advises instead: it has no pose file, and pairs images and poses itself
VIRTUAL_ADVICE = ("the virtual testbed pairs its images and poses itself, so its calibration poses do not determine "
                  "the offsets: plan more of them (plan.n_calibration), or check the target folder's [mockup] board "
                  "and fixture")


def advice_for(message: str, backend: str) -> str:
    """A refusal's message with the advice that fits the backend that made the captures."""
    if backend != "virtual":
        return message
    return message.replace(INLIER_ADVICE, VIRTUAL_ADVICE).replace(RESULT_ADVICE, VIRTUAL_ADVICE)


def check_inliers(name: str, inliers: int, total: int) -> None:
    """The offsets must explain most samples: when the robust solve keeps fewer than half,
    it has found a pattern in noise, not the calibration."""
    if inliers < 0.5 * total:
        raise InconsistentPatternError(
            f"calibration refused: the {name} offsets fit only {inliers} of {total} samples (the others are outliers "
            f"beyond median + outlier_k robust sigmas); {INLIER_ADVICE}")


def check_result(name: str, in_sample: dict[str, list[float]], cross_validated: dict[str, list[float]] | None,
                 intrinsics: obs.EstimatedCamera, limits: CalibrateConfig,
                 cross_validation: Folds | None = None) -> None:
    """Refuse a calibration whose errors are absurd for any real set-up (the thresholds and
    why: ``CalibrateConfig`` and docs/accuracy.md): the in-sample fit's, and the
    cross-validated ones of the folds that determine the offsets (``cross_validated`` None:
    too few such folds to judge, ``cross_validation`` says which were left out)."""
    diagonal = float(np.hypot(intrinsics.width, intrinsics.height))
    left_out = cross_validation.undetermined_folds if cross_validation is not None else ()
    folds = cross_validation.folds if cross_validation is not None else None
    note = (f"; fold(s) {', '.join(map(str, left_out))} of {folds} could not be judged (their training samples do "
            "not determine the offsets) and are left out" if left_out else "")
    judged = [("in-sample", in_sample)]
    if cross_validated is not None:
        judged.append(("cross-validated", cross_validated))
    elif left_out:
        note += "; too few folds are determined to judge, so the in-sample fit alone does"
    for kind, values in judged:
        e_r, e_p = values["E_R_rad"][0], values["E_p_px"][0]
        if e_r > limits.max_rotation_error_rad or e_p > limits.max_reprojection_fraction * diagonal:
            raise InconsistentPatternError(
                f"calibration refused: {name} {kind} E_R {np.degrees(e_r):.3g} deg, E_p {e_p:.4g} px (at most "
                f"{np.degrees(limits.max_rotation_error_rad):g} deg and {limits.max_reprojection_fraction:g} of the "
                f"{diagonal:.0f} px diagonal): the offsets do not predict the pattern; {RESULT_ADVICE}{note}")
