"""Any URDF arm's calibration (issue 57): the structural rank test names what no data can
separate, and the fit recovers seeded errors within the covariance it reports."""

from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from manifests.sidecars.arm_fit import ChainFit, RobotCorrection
from manifests.sidecars.base import Fields, SidecarError
from stages.common import arms, rwhe
from stages.common import geometry as g
from stages.common.robots import identification as ident
from stages.common.robots import lost_motion
from stages.common.robots.errors import Holders
from stages.common.robots.facility import load_facility

FACILITIES = Path(__file__).resolve().parents[3] / "facilities"
PAYLOAD = arms.Payload(12.0, (0.0, 0.0, 0.1), (("minus_x", (0.0, 0.05, 0.2)),))
UP = np.array([0.0, 0.0, 1.0])
SETTINGS = SimpleNamespace(
    world_up=(0.0, 0.0, 1.0), arm_prior_joint_rad=2e-3, arm_prior_length_m=2e-3, arm_prior_frame_rad=2e-4,
    arm_prior_base_m=2e-3, arm_prior_base_rad=2e-3, arm_prior_rail_scale=1e-4,
    arm_prior_compliance_rad_per_nm=3e-5, joint_compliance="on", fixture_anisotropy="on",
    fixture_anisotropy_prior=0.5, arm_prior_lost_motion_rad=2.9e-4, lost_motion="auto",
    backlash_preload_nm=1e9, link_mass_uncertainty=0.25, fixture_play="auto",
    fixture_play_prior_rad=1e-3)  # every joint rests on the flank its last move left it on, as the draws' are
OFFSETS = rwhe.Solution(g.make_transform(g.rotvec_to_matrix([0.1, 0.2, 0.3]), [0.01, 0.02, 0.1]),
                        {"minus_x": g.make_transform(g.rotvec_to_matrix([0.3, -0.2, 0.1]), [0.0, 0.05, 0.02])})


@pytest.fixture(scope="module")
def holders() -> Holders:
    """A UR10 on a rail carries the camera, a UR5 the target (a facility of issue 57's)."""
    return Holders.of(load_facility(FACILITIES / "ur_rail_pair"))


def _dropped(holders: Holders, seed: int = 0) -> dict[str, str]:
    params = np.concatenate([np.zeros(holders.size), rwhe.pack(OFFSETS, ["minus_x"], False)])
    return ident.identifiable(holders, ["minus_x"], False, params, np.ones(len(params), bool), PAYLOAD, UP, seed)


def test_what_no_data_can_separate_is_named_with_what_absorbs_it(holders):
    dropped = _dropped(holders)
    # the flanges' frames are the hand-eye offsets'
    for robot in ("ur10_camera", "ur5_target"):
        for axis in ("rx", "ry", "rz", "x", "y", "z"):
            assert "hand-eye" in dropped[f"{robot}.flange.{axis}"]
    # a frame's turn about its own joint's axis (the UR's z of the pan) is that joint's zero offset
    assert dropped["ur10_camera.shoulder_pan_joint.origin.rz"] == "a combination of ur10_camera.shoulder_pan_joint.zero"
    # the pan of a floor robot carries no gravity torque: its compliance moves nothing
    assert dropped["ur5_target.shoulder_pan_joint.compliance"].startswith("moves no pose")
    # only the bases' relative pose counts: five of the target base's six go with the camera's
    # (the rail's axis, seen from the target, keeps one)
    target_base = [n for n in dropped if n.startswith("ur5_target.shoulder_pan_joint.origin.")]
    assert len(target_base) == 5
    # every joint's zero offset but the last (the flange's turn) is kept
    assert not any(n.endswith(".zero") for n in dropped if "wrist_3" not in n)


def test_the_rank_test_is_structural_not_an_accident_of_the_draw(holders):
    assert set(_dropped(holders, 0)) == set(_dropped(holders, 7))


@pytest.mark.parametrize("seed", [3, 4])
def test_the_fit_recovers_seeded_errors_within_its_covariance(holders, seed):
    rng = np.random.default_rng(seed)
    dropped = _dropped(holders)
    prior = holders.priors(2e-3, 2e-3, 2e-4, (2e-3, 2e-3), 1e-4, 3e-5, 2.9e-4)
    kept = np.array([name not in dropped for name in holders.names])
    truth = np.where(kept, rng.normal(0.0, 0.5, holders.size) * prior, 0.0)
    m = ident._draw_configurations(holders, ["minus_x"], PAYLOAD, UP, seed + 100).subset(np.arange(96) < 48)
    params = np.concatenate([truth, rwhe.pack(OFFSETS, ["minus_x"], False)])
    a = ident.predict_batch(holders, params[None], ["minus_x"], False, m, UP)[0]
    noise = np.concatenate([rng.normal(0, 1e-4, (48, 3)), rng.normal(0, 1e-4, (48, 3))], axis=1)
    a = a @ rwhe.transform_from_vector(noise)
    start = rwhe.Solution(OFFSETS.z @ rwhe.transform_from_vector(np.array([1e-3, 0, 0, 1e-3, 0, 0])),
                          dict(OFFSETS.x))
    fitted = ident.fit(holders, SETTINGS, a, m, start, False, PAYLOAD)
    assert set(fitted.dropped) == set(dropped)
    # every joint's lost motion is kept: the draws' moves leave joints on either flank
    assert not [name for name in dropped if name.endswith(".lost_motion")]
    sigma = np.sqrt(np.diag(fitted.covariance)[:holders.size])[kept]
    z = (fitted.params[:holders.size][kept] - truth[kept]) / sigma
    assert 0.6 < np.sqrt(np.mean(z**2)) < 1.4  # honest: neither over- nor under-confident
    assert np.all(np.abs(z) < 4.5)
    # and the parameters improve the poses where the calibration never was
    far = ident._draw_configurations(holders, ["minus_x"], PAYLOAD, UP, seed + 200)
    true_far = ident.predict_batch(holders, params[None], ["minus_x"], False, far, UP)[0]
    nominal = np.concatenate([np.zeros(holders.size), fitted.params[holders.size:]])
    errors = {name: np.linalg.norm(ident.predict_batch(holders, p[None], ["minus_x"], False, far, UP)[0][:, :3, 3]
                                   - true_far[:, :3, 3], axis=1).mean()
              for name, p in (("fitted", fitted.params), ("nominal", nominal))}
    assert errors["fitted"] < 0.3 * errors["nominal"]


def test_the_record_round_trips_and_a_bad_key_is_named(holders):
    m = ident._draw_configurations(holders, ["minus_x"], PAYLOAD, UP, 1).subset(np.arange(96) < 40)
    a = ident.predict_batch(holders, np.concatenate([np.zeros(holders.size),
                                                     rwhe.pack(OFFSETS, ["minus_x"], False)])[None],
                            ["minus_x"], False, m, UP)[0]
    record = ident.fit(holders, SETTINGS, a, m, OFFSETS, False, PAYLOAD).record()
    data = record.to_json()
    assert ChainFit.from_fields(Fields(data, "calibration.json", "kuka.arm_kinematics.chains.")) == record
    assert [r.robot for r in record.robots] == ["ur10_camera", "ur5_target"]
    for key, value, message in (("parameter_names", data["parameter_names"][:-1], r"chains\.parameter_names"),
                                ("parameters", data["parameters"][:10], r"chains\.parameters"),
                                ("weak", {"ur5_target.elbow": 0.9}, r"'ur5_target\.elbow' is not one of")):
        bad = {**data, key: value}
        with pytest.raises(SidecarError, match=message):
            ChainFit.from_fields(Fields(bad, "calibration.json", "kuka.arm_kinematics.chains."))
    data["robots"][1]["zero_offsets"] = [0.0]
    with pytest.raises(SidecarError, match=r"chains\.robots\[1\]\.zero_offsets"):
        ChainFit.from_fields(Fields(data, "calibration.json", "kuka.arm_kinematics.chains."))


def test_a_static_mount_has_no_parameters():
    holders = Holders.of(load_facility(FACILITIES / "ur10_tripod"))
    assert [robot.role for robot in holders.robots] == ["camera"]
    assert isinstance(holders.target, np.ndarray) and holders.size == holders.robots[0].size


def test_the_calibrated_urdf_moves_as_the_fitted_arm(holders, tmp_path):
    """Its forward kinematics of the controller's readings is the fitted model's (compliance
    and the rail's scale aside, which it keeps in a comment)."""
    from stages.common.robots.calibrated_urdf import calibrated_urdf
    from stages.common.robots.chain import load_chain

    rng = np.random.default_rng(9)
    robot = holders.robots[0]
    prior = holders.priors(2e-3, 2e-3, 2e-4, (2e-3, 2e-3), 1e-4, 3e-5)[:robot.size]
    params = rng.normal(0.0, 1.0, robot.size) * prior
    zero, frames, _, compliance, lost = robot.split(params[None])
    correction = RobotCorrection(robot.robot, "camera", robot.chain.joint_names, tuple(zero[0]),
                                 tuple(tuple(f) for f in frames[0]), 0.0, tuple(compliance[0]), tuple(lost[0]))
    text = calibrated_urdf(FACILITIES / "ur_rail_pair" / "ur10.urdf", "tool0", correction, "a test")
    (tmp_path / "ur10.urdf").write_text(text)
    chain = load_chain(tmp_path / "ur10.urdf", "base_link", "tool0")
    joints = rng.uniform(-np.pi, np.pi, (20, robot.joints))
    params_rigid = params.copy()
    params_rigid[-2 * robot.joints:] = 0.0  # no compliance, no lost motion
    expected = robot.flanges(params_rigid[None], joints, np.zeros(20), np.zeros((20, robot.joints)))[0]
    got = robot.base_at(np.zeros(20)) @ chain.forward(joints)
    assert np.allclose(got, expected, atol=1e-9)
    assert "joint compliance" in text and "joint lost motion" in text and "a test" in text


def test_the_observability_measure_names_what_the_poses_leave_to_the_prior(holders):
    """Poses that never move the rail cannot fix its scale: the measure says so, and its
    smallest singular value falls; poses over the rail's travel determine it."""
    prior = holders.priors(2e-3, 2e-3, 2e-4, (2e-3, 2e-3), 1e-4, 3e-5)
    spread = ident._draw_configurations(holders, ["minus_x"], PAYLOAD, UP, 21).subset(np.arange(96) < 48)
    fixed = ident.measure(holders, (spread.camera_joints, spread.target_joints), np.full(48, 1.0),
                          spread.fixtures, PAYLOAD, UP)
    from stages.common.robots.observability import observability

    moving, still = (observability(holders, m, prior, PAYLOAD, UP) for m in (spread, fixed))
    assert "ur10_camera.rail.scale" not in moving.weak
    assert still.weak["ur10_camera.rail.scale"] > 0.99
    assert still.smallest < moving.smallest and still.under_prior > moving.under_prior
    assert "ur10_camera.rail.scale (100% of its prior)" in still.describe(48)


def test_the_greedy_choice_takes_the_pose_that_determines_the_worst_direction():
    """Two parameters, one free offset: after a pose that measures only the first
    parameter, the next slot takes the candidate that measures the second, not a second
    copy of the first (which would raise the determinant's share of the first alone)."""
    from stages.common.robots.observability import Rows, choose, measure_of

    first = np.zeros((6, 2))
    first[0, 0] = 10.0
    second = np.zeros((6, 2))
    second[1, 1] = 3.0
    offsets = np.zeros((6, 1))
    offsets[2, 0] = 1.0  # the offset is measured by a row no arm parameter moves
    rows = Rows(np.stack([first, first * 2, second]), np.stack([offsets] * 3), ("a", "b"))
    assert choose(rows, [[0], [1, 2]]) == [0, 2]
    # where the prior still holds a direction either way, the larger determinant decides
    assert choose(rows, [[2, 0], [1, 2]]) == [0, 2]
    assert measure_of(Rows(rows.arm[[0, 2]], rows.offsets[[0, 2]], ("a", "b"))).weak == {}
    assert set(measure_of(Rows(rows.arm[[0, 1]], rows.offsets[[0, 1]], ("a", "b"))).weak) == {"b"}


def test_a_lost_motion_no_capture_can_see_is_named_and_held(holders):
    """Captures without times give no flank: the fit holds every unloaded joint's lost
    motion at zero and says why, instead of reporting its prior as a weak estimate."""
    m = ident._draw_configurations(holders, ["minus_x"], PAYLOAD, UP, 5).subset(np.arange(96) < 48)
    blind = ident.measure(holders, (m.camera_joints, m.target_joints), m.rail_m, m.fixtures, PAYLOAD, UP)
    params = np.concatenate([np.zeros(holders.size), rwhe.pack(OFFSETS, ["minus_x"], False)])
    a = ident.predict_batch(holders, params[None], ["minus_x"], False, blind, UP)[0]
    fitted = ident.fit(holders, SETTINGS, a, blind, OFFSETS, False, PAYLOAD)
    lost = [name for name in holders.names if name.endswith(".lost_motion")]
    assert all("capture_time_s" in fitted.dropped[name] for name in lost)
    assert not set(lost) & set(fitted.weak())


def _without_lost_motion(holders: Holders) -> tuple[ident.Measured, np.ndarray]:
    """48 drawn configurations and their PnP-like poses (4, 4) of arms at their nominal
    kinematics, 0.1 mrad and 0.1 mm of noise: no lost motion for the captures to show."""
    m = ident._draw_configurations(holders, ["minus_x"], PAYLOAD, UP, 8).subset(np.arange(96) < 48)
    rng = np.random.default_rng(8)
    params = np.concatenate([np.zeros(holders.size), rwhe.pack(OFFSETS, ["minus_x"], False)])
    truth = ident.predict_batch(holders, params[None], ["minus_x"], False, m, UP)[0]
    noise = rwhe.transform_from_vector(np.concatenate([rng.normal(0, 1e-4, (48, 3)), rng.normal(0, 1e-4, (48, 3))],
                                                      axis=1))
    return m, truth @ noise


def test_lost_motion_the_captures_do_not_show_is_not_fitted(holders):
    """Under ``auto`` the joints' lost motions are fitted only where the captures show them
    (an F test): arms without any keep their parameters' noise out of the dataset's poses."""
    m, a = _without_lost_motion(holders)
    fitted = ident.fit(holders, SETTINGS, a, m, OFFSETS, False, PAYLOAD)
    lost = [name for name in holders.names if name.endswith(".lost_motion")]
    assert all("F test" in fitted.dropped[name] for name in lost)
    assert not np.any(fitted.params[[holders.names.index(name) for name in lost]])


def test_a_fold_holds_what_the_whole_calibration_held_in_one_fit(holders, monkeypatch):
    """Cross-validation folds take the whole calibration's verdicts (``Fitted.verdicts``): the
    lost motions it held are held untested, in one fit instead of three, the structural rank
    test is not run again, and the result is the fit the fold's own tests would have chosen."""
    m, a = _without_lost_motion(holders)
    tested = ident.fit(holders, SETTINGS, a, m, OFFSETS, False, PAYLOAD)
    assert tested.held == frozenset({"lost motion"})  # the captures show none (the test above)
    assert tested.unidentifiable and set(dict(tested.unidentifiable)) <= set(tested.dropped)
    fits, ranks = [], []
    counted, ranked = arms.map_fit, ident.identifiable
    monkeypatch.setattr(arms, "map_fit", lambda *args, **kwargs: fits.append(1) or counted(*args, **kwargs))
    monkeypatch.setattr(ident, "identifiable", lambda *args, **kwargs: ranks.append(1) or ranked(*args, **kwargs))
    fold = ident.fit(holders, SETTINGS, a, m, OFFSETS, False, PAYLOAD, verdicts=tested.verdicts())
    assert len(fits) == 1 and not ranks
    np.testing.assert_array_equal(fold.params, tested.params)
    assert fold.unidentifiable == tested.unidentifiable
    lost = [name for name in holders.names if name.endswith(".lost_motion")]
    assert all("as on the whole calibration" in fold.dropped[name] for name in lost)


def test_a_fold_of_other_fixtures_runs_its_own_rank_test(holders, monkeypatch):
    """The rank test's verdict depends on the fixtures whose offsets absorb the arms': a fold
    that holds other fixtures than the whole calibration tests for itself."""
    m, a = _without_lost_motion(holders)
    tested = ident.fit(holders, SETTINGS, a, m, OFFSETS, False, PAYLOAD)
    ranks = []
    ranked = ident.identifiable
    monkeypatch.setattr(ident, "identifiable", lambda *args, **kwargs: ranks.append(1) or ranked(*args, **kwargs))
    other = ident.Verdicts(("plus_x",), (), tested.held)
    fold = ident.fit(holders, SETTINGS, a, m, OFFSETS, False, PAYLOAD, verdicts=other)
    assert len(ranks) == 1 and fold.unidentifiable == tested.unidentifiable


def test_lost_motion_switched_off_is_named_and_left_to_the_rating(holders):
    """``calibrate.lost_motion = off``: the lost motions are held and named as such, so that
    fuse takes the gearboxes' rating for every unloaded joint instead of a fit of zero."""
    from dataclasses import replace as replaced

    m = ident._draw_configurations(holders, ["minus_x"], PAYLOAD, UP, 6).subset(np.arange(96) < 48)
    params = np.concatenate([np.zeros(holders.size), rwhe.pack(OFFSETS, ["minus_x"], False)])
    a = ident.predict_batch(holders, params[None], ["minus_x"], False, m, UP)[0]
    settings = SimpleNamespace(**{**vars(SETTINGS), "lost_motion": "off"})
    record = ident.fit(holders, settings, a, m, OFFSETS, False, PAYLOAD).record()
    lost = [name for name in holders.names if name.endswith(".lost_motion")]
    assert all("calibrate.lost_motion = off" in record.dropped[name] for name in lost)
    rating = (2.9e-4,) * 3 + (5.8e-4,) * 3
    off = lost_motion.flank_variances(holders, m, record, rating)
    assert off.max() > 0  # the unloaded joints carry their rating
    fitted = replaced(record, dropped={k: v for k, v in record.dropped.items() if k not in lost})
    assert lost_motion.flank_variances(holders, m, fitted, rating).max() == 0  # known flanks, fitted: none


def _played(m: ident.Measured) -> ident.Measured:
    """``m`` as one session in its rows' order: each capture's target joints before it."""
    before = np.roll(m.target_joints, 1, axis=0)
    before[0] = np.nan
    return replace(m, target_before=before)


@pytest.mark.parametrize("play_rad", [4e-4, 0.0])
def test_a_fixtures_play_is_fitted_where_the_captures_show_it(holders, play_rad):
    """A compliant fixture whose tilt lags its change by ``play_rad``: the fit finds the play
    within its covariance and keeps the arms' lost motions unbiased; where there is none, the
    F test holds it at zero and says so."""
    rng = np.random.default_rng(11)
    names = ["minus_x"]
    m = _played(ident._draw_configurations(holders, names, PAYLOAD, UP, 31).subset(np.arange(96) < 64))
    dropped = _dropped(holders)
    prior = holders.priors(2e-3, 2e-3, 2e-4, (2e-3, 2e-3), 1e-4, 3e-5, 2.9e-4)
    kept = np.array([name not in dropped for name in holders.names])
    truth = np.where(kept, rng.normal(0.0, 0.5, holders.size) * prior, 0.0)
    offsets = rwhe.Solution(OFFSETS.z, dict(OFFSETS.x), {"minus_x": np.array([4e-3, -3e-3, 1e-3])},
                            {"minus_x": np.zeros(6)}, {"minus_x": play_rad})
    params = np.concatenate([truth, rwhe.pack(offsets, names, True, True, True)])
    a = ident.predict_batch(holders, params[None], names, True, m, UP)[0]
    a = a @ rwhe.transform_from_vector(rng.normal(0, 5e-5, (64, 6)))
    start = rwhe.Solution(offsets.z, dict(offsets.x), dict(offsets.compliance), dict(offsets.anisotropy))
    fitted = ident.fit(holders, SETTINGS, a, m, start, True, PAYLOAD)
    index = holders.size + rwhe.play_slice(names).start
    if play_rad:
        assert fitted.play_why == ""
        assert abs(fitted.params[index] - play_rad) < 4 * np.sqrt(fitted.covariance[index, index])
        lost = [i for i, n in enumerate(holders.names) if n.endswith(".lost_motion") and n not in fitted.dropped]
        z = (fitted.params[lost] - truth[lost]) / np.sqrt(np.diag(fitted.covariance)[lost])
        assert np.all(np.abs(z) < 4.5)
    else:
        assert "F test of the 1 plays" in fitted.play_why and fitted.params[index] == 0.0
        assert fitted.offsets.play == {"minus_x": 0.0}


def test_a_lost_motion_whose_flank_the_load_decides_is_held_and_named():
    """Above the preload a joint rests on its loaded flank whatever its last move: a lost
    motion seen on too few captures whose flank the move decides beyond the link masses'
    doubt would take up what those masses misplace, so it is held and said so. TRON's KR
    16-2, whose URDF carries the data sheet's link masses: its shoulder and elbow lift the
    arm (hundreds of N m), its last wrist carries nothing."""
    kr16 = Holders.of(load_facility(None))
    m = ident._draw_configurations(kr16, ["minus_x"], PAYLOAD, UP, 5, 15.0).subset(np.arange(96) < 48)
    free = np.ones(kr16.size, bool)
    held = lost_motion.loaded_flanks(kr16, m, free, 15.0, 0.25, UP)
    for robot in ("camera_robot", "target_robot"):
        assert "its load decides its flank" in held[f"{robot}.joint_a2.lost_motion"]
        assert f"{robot}.joint_a6.lost_motion" not in held
    exact = lost_motion.loaded_flanks(kr16, m, free, 15.0, 0.0, UP)
    assert set(exact) <= set(held)  # the masses' doubt only ever holds more
    assert not lost_motion.loaded_flanks(kr16, m, free, 1e9, 0.25, UP)  # no preload reached: none
    blind = ident.measure(kr16, (m.camera_joints, m.target_joints), m.rail_m, m.fixtures, PAYLOAD, UP, None, 1e9)
    unordered = lost_motion.loaded_flanks(kr16, blind, free, 1e9, 0.25, UP)  # unloaded, but no move's order known
    assert all("order of the moves" in why for why in unordered.values()) and len(unordered) == 12


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_batch_of_one_parameter_steps_predicts_each_row_as_it_would_alone(holders, seed):
    """predict_batch evaluates each robot's chain only for the rows that move it
    (``distinct_rows``): a finite-difference batch (steps of either robot's parameters, of
    the offsets, rows repeated, a row of -0.0 where the first has 0.0) gives every row the
    bits that row gives alone."""
    rng = np.random.default_rng(seed)
    m = ident._draw_configurations(holders, ["minus_x"], PAYLOAD, UP, seed)
    params = np.concatenate([rng.normal(0.0, 1e-4, holders.size), rwhe.pack(OFFSETS, ["minus_x"], False)])
    params[0] = 0.0
    steps = rng.choice(len(params), 12, replace=False)
    batch = np.repeat(params[None], 16, axis=0)
    batch[1 + np.arange(12), steps] += 1e-7
    batch[13, 0] = -0.0  # the same number, other bits: evaluated on its own
    together = ident.predict_batch(holders, batch, ["minus_x"], False, m, UP)
    alone = np.stack([ident.predict_batch(holders, row[None], ["minus_x"], False, m, UP)[0] for row in batch])
    assert together.tobytes() == alone.tobytes()
    arm = batch[:, :holders.size]
    rows, which = ident.distinct_rows(arm)
    assert arm[rows][which].tobytes() == arm.tobytes() and len(rows) == 1 + np.sum(steps < holders.size) + 1
