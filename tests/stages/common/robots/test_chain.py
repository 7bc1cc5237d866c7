"""URDF serial chains (stages/common/robots/chain.py): the forward kinematics agree with an
independent evaluation of the same URDF (yourdfpy's scene graph) and, for TRON's KR 16-2,
with the closed-form arm model tested against ROS-Industrial's chain; broken URDFs are
refused naming the file and the element."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from speedplus.errors import FileError
from stages.common.facilities import builtin_folder
from stages.common.kinematics import KR16_2, forward
from stages.common.robots.chain import load_chain

TESTS = Path(__file__).resolve().parents[3] / "facilities"
ARMS = [(builtin_folder() / "kr16_2.urdf", "tool0"), (TESTS / "abb_rail" / "irb4600_60_205.urdf", "tool0"),
        (TESTS / "ur10_tripod" / "ur10.urdf", "tool0")]


def test_the_kr16_2_urdf_is_the_closed_form_arm():
    chain = load_chain(builtin_folder() / "kr16_2.urdf", "base_link", "tool0")
    joints = np.random.default_rng(3).uniform(KR16_2.lower, KR16_2.upper, size=(500, 6))
    assert np.abs(chain.forward(joints) - forward(KR16_2, joints)).max() < 1e-12
    assert np.allclose(chain.lower, KR16_2.lower, atol=1e-12) and np.allclose(chain.upper, KR16_2.upper, atol=1e-12)


@pytest.mark.parametrize(("urdf", "flange"), ARMS, ids=lambda value: getattr(value, "stem", value))
def test_forward_kinematics_agree_with_yourdfpys_scene_graph(urdf, flange):
    import yourdfpy

    chain = load_chain(urdf, "base_link", flange)
    independent = yourdfpy.URDF.load(str(urdf), load_meshes=False, build_collision_scene_graph=False)
    rng = np.random.default_rng(7)
    for joints in rng.uniform(chain.lower, chain.upper, size=(25, chain.dof)):
        independent.update_cfg(dict(zip(chain.joint_names, joints, strict=True)))
        expected = independent.get_transform(flange, "base_link")
        assert np.abs(chain.forward(joints) - expected).max() < 1e-9


@pytest.mark.parametrize(("urdf", "flange"), ARMS, ids=lambda value: getattr(value, "stem", value))
def test_the_jacobian_is_the_derivative_of_the_flange_pose(urdf, flange):
    from stages.common import geometry as g

    chain = load_chain(urdf, "base_link", flange)
    joints = np.random.default_rng(11).uniform(chain.lower, chain.upper) * 0.5
    jacobian, step = chain.jacobian(joints), 1e-6
    base = chain.forward(joints)
    for index in range(chain.dof):
        moved = chain.forward(joints + step * np.eye(chain.dof)[index])
        linear = (moved[:3, 3] - base[:3, 3]) / step
        angular = g.matrix_to_rotvec(moved[:3, :3] @ base[:3, :3].T) / step
        assert np.allclose(jacobian[:, index], np.concatenate([linear, angular]), atol=1e-5)


@pytest.mark.parametrize(("urdf", "flange"), ARMS, ids=lambda value: getattr(value, "stem", value))
def test_the_reach_bound_holds_over_the_joint_ranges(urdf, flange):
    chain = load_chain(urdf, "base_link", flange)
    joints = np.random.default_rng(1).uniform(chain.lower, chain.upper, size=(5000, chain.dof))
    distances = np.linalg.norm(chain.forward(joints)[:, :3, 3], axis=1)
    assert distances.max() <= chain.reach_bound_m and chain.reach_m() <= chain.reach_bound_m


def test_capsules_come_from_collision_elements_or_the_links(tmp_path):
    abb = load_chain(TESTS / "abb_rail" / "irb4600_60_205.urdf", "base_link", "tool0")
    # its <collision> cylinders and sphere, then a link capsule for each wrist link without one
    assert [(c.joint, round(c.radius_m, 3)) for c in abb.capsules] == [(0, 0.18), (1, 0.12), (2, 0.1), (5, 0.07),
                                                                        (3, 0.06), (4, 0.06)]
    ur10 = load_chain(TESTS / "ur10_tripod" / "ur10.urdf", "base_link", "tool0")
    assert len(ur10.capsules) == 6 and {c.radius_m for c in ur10.capsules} == {0.06}  # one per link
    # a capsule moves with its link: at any joints its ends stay where the link's frame takes them
    a, b, _ = ur10.capsules_in_base(np.zeros(6))
    assert np.allclose(b[-1], ur10.forward(np.zeros(6))[:3, 3], atol=1e-9)


def _urdf(tmp_path: Path, body: str) -> Path:
    path = tmp_path / "arm.urdf"
    path.write_text(f'<robot name="arm">{body}</robot>')
    return path


LINKS = '<link name="base_link"/><link name="a"/><link name="tool0"/>'
JOINT = ('<joint name="j1" type="{kind}"><parent link="base_link"/><child link="a"/><axis xyz="0 0 1"/>{limit}'
         '</joint><joint name="j2" type="fixed"><parent link="a"/><child link="tool0"/>'
         '<origin xyz="0.5 0 0"/></joint>')
LIMIT = '<limit lower="-1" upper="1" effort="1" velocity="1"/>'


@pytest.mark.parametrize(("body", "flange", "message"), [
    (LINKS + JOINT.format(kind="revolute", limit=LIMIT).replace("</robot>", ""), "nowhere",
     'no <link name="nowhere">'),
    (LINKS + JOINT.format(kind="floating", limit=""), "tool0", '<joint name="j1"> is \'floating\''),
    (LINKS + JOINT.format(kind="revolute", limit=""), "tool0", '<joint name="j1">: a revolute joint needs <limit'),
    (LINKS + JOINT.format(kind="revolute", limit='<limit lower="1" upper="-1" effort="1" velocity="1"/>'), "tool0",
     "upper -1.0 is not above lower 1.0"),
    (LINKS + '<link name="b"/>' + JOINT.format(kind="revolute", limit=LIMIT), "b", "no serial chain joins them"),
    (LINKS + JOINT.format(kind="revolute", limit=LIMIT).replace("</joint><joint", "</joint<joint"), "tool0",
     "not valid XML"),
    (LINKS.replace('<link name="a"/>', '<link name="a"><inertial><mass value="-3"/></inertial></link>')
     + JOINT.format(kind="revolute", limit=LIMIT), "tool0", '<link name="a">: <mass value> -3.0 is not a mass'),
    # what stages/common/robots/urdf.py refuses where a lenient reader would guess
    (LINKS.replace('<link name="a"/>', '<link name="a"><collision><geometry><box/></geometry></collision></link>')
     + JOINT.format(kind="revolute", limit=LIMIT), "tool0", '<link name="a">: <box size> must be given, positive'),
    (LINKS.replace('<link name="a"/>', '<link name="a"><collision/></link>')
     + JOINT.format(kind="revolute", limit=LIMIT), "tool0", '<link name="a">: a <collision> has no <geometry> shape'),
    (LINKS + JOINT.format(kind="revolute", limit=LIMIT).replace('<parent link="base_link"/>', '<parent link="nope"/>'),
     "tool0", '<joint name="j1"> names <parent link="nope">, which the file does not hold'),
    (LINKS + JOINT.format(kind="revolute", limit=LIMIT).replace('<parent link="base_link"/>', '<parent link="tool0"/>'),
     "tool0", "closes a loop of joints"),
    (LINKS + JOINT.format(kind="revolute", limit=LIMIT).replace('xyz="0.5 0 0"', 'xyz="0.5 0"'), "tool0",
     '<joint name="j2">: <origin xyz="0.5 0"> is not 3 finite number(s)'),
    (LINKS + JOINT.format(kind="revolute", limit=LIMIT.replace('upper="1"', 'upper="one"')), "tool0",
     '<joint name="j1">: <limit upper="one"> is not 1 finite number(s)'),
    (LINKS + JOINT.format(kind="revolute", limit=LIMIT).replace('<parent link="base_link"/>', ""), "tool0",
     '<joint name="j1">: has no <parent link>'),
    (LINKS.replace('<link name="a"/>', '<link name="a"><collision><geometry><box size="1 nan 1"/></geometry>'
                   '</collision></link>') + JOINT.format(kind="revolute", limit=LIMIT), "tool0",
     '<link name="a">: <box size="1 nan 1"> is not 3 finite number(s)'),
])
def test_a_bad_urdf_is_refused_naming_the_element(tmp_path, body, flange, message):
    path = _urdf(tmp_path, body)
    with pytest.raises(FileError) as raised:
        load_chain(path, "base_link", flange)
    assert str(raised.value).startswith(str(path)) and message in str(raised.value), raised.value


def test_a_file_whose_root_is_not_a_robot_is_refused(tmp_path):
    path = tmp_path / "arm.urdf"
    path.write_text("<sdf/>")
    with pytest.raises(FileError, match="the root element is <sdf>, not <robot>"):
        load_chain(path, "base_link", "tool0")


@pytest.mark.parametrize("seed", range(6))
def test_origins_axes_and_shapes_are_read_as_yourdfpy_reads_them(tmp_path, seed):
    """A seeded chain of three revolute joints with arbitrary origins (xyz, roll-pitch-yaw),
    unnormalised axes and a collision box each: our reader (``robots/urdf.py``) and
    yourdfpy's give the same forward kinematics, and the boxes' sizes and origins."""
    import yourdfpy

    rng = np.random.default_rng(seed)

    def origin() -> str:
        xyz, rpy = rng.uniform(-0.5, 0.5, 3), rng.uniform(-np.pi, np.pi, 3)
        return f'<origin xyz="{" ".join(str(float(v)) for v in xyz)}" rpy="{" ".join(str(float(v)) for v in rpy)}"/>'

    links = ['<link name="base_link"/>'] + [
        f'<link name="l{i}"><collision>{origin()}<geometry><box size="0.1 0.2 {0.3 + i}"/></geometry></collision>'
        '</link>' for i in range(3)]
    joints = [f'<joint name="j{i}" type="revolute"><parent link="{"base_link" if i == 0 else f"l{i - 1}"}"/>'
              f'<child link="l{i}"/>{origin()}<axis xyz="{" ".join(str(float(v)) for v in rng.normal(size=3))}"/>'
              '<limit lower="-3" upper="3" effort="1" velocity="1"/></joint>' for i in range(3)]
    path = _urdf(tmp_path, "".join(links + joints))
    chain = load_chain(path, "base_link", "l2")
    independent = yourdfpy.URDF.load(str(path), load_meshes=False, build_collision_scene_graph=False)
    for joints_rad in rng.uniform(-3, 3, size=(10, 3)):
        independent.update_cfg(dict(zip(chain.joint_names, joints_rad, strict=True)))
        assert np.abs(chain.forward(joints_rad) - independent.get_transform("l2", "base_link")).max() < 1e-12
    from stages.common.robots.urdf import read_urdf

    ours = {link.name: link for link in read_urdf(path).links}
    for link in independent.robot.links:
        for mine, theirs in zip(ours[link.name].collisions, link.collisions, strict=True):
            np.testing.assert_allclose(mine.origin, theirs.origin, atol=1e-15)
            np.testing.assert_array_equal(mine.geometry.box, theirs.geometry.box.size)


def test_a_links_mass_hangs_on_the_joint_that_moves_it(tmp_path):
    """An <inertial> on a moving link, and one on a link fixed after it, both turn with that
    joint: 2 kg at 0.5 m and 1 kg at the flange's 0.5 + 0.25 m, under gravity along -y of
    the base, load the joint by their weights' levers."""
    body = LINKS.replace('<link name="a"/>', '<link name="a"><inertial><origin xyz="0.5 0 0"/><mass value="2"/>'
                         '</inertial></link>').replace(
        '<link name="tool0"/>', '<link name="tool0"><inertial><origin xyz="0.25 0 0"/><mass value="1"/>'
        '</inertial></link>') + JOINT.format(kind="revolute", limit=LIMIT)
    chain = load_chain(_urdf(tmp_path, body), "base_link", "tool0")
    assert [(m.joint, m.mass_kg) for m in chain.masses] == [(0, 2.0), (0, 1.0)]
    torque = chain.gravity_torques(np.zeros((1, 1)), np.array([[0.0, -9.81, 0.0]]))
    np.testing.assert_allclose(torque, [[-9.81 * (2 * 0.5 + 1 * 0.75)]])


def test_a_prismatic_joint_among_revolute_ones_moves_as_yourdfpy_says(tmp_path):
    """A chain of revolute, prismatic (a rail or a linear wrist) and continuous joints: each
    joint's motion (``SerialChain.motions``, every joint in one pass) and the chain's frames
    agree with an independent reading of the URDF, and the inverse kinematics' Jacobians
    with the chain's own."""
    import yourdfpy

    from stages.common.robots.inverse import jacobians

    body = '<link name="base_link"/><link name="a"/><link name="b"/><link name="c"/><link name="tool0"/>'
    for name, kind, parent, child, axis, origin in [
            ("j1", "revolute", "base_link", "a", "0 0 1", "0 0 0.3"),
            ("j2", "prismatic", "a", "b", "0.6 0 0.8", "0.2 0 0"),
            ("j3", "continuous", "b", "c", "0 1 0", "0 0.1 0.4")]:
        limit = LIMIT if kind != "continuous" else '<limit effort="1" velocity="1"/>'
        body += (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
                 f'<origin xyz="{origin}" rpy="0.1 -0.2 0.3"/><axis xyz="{axis}"/>{limit}</joint>')
    body += ('<joint name="j4" type="fixed"><parent link="c"/><child link="tool0"/>'
             '<origin xyz="0 0 0.15"/></joint>')
    path = _urdf(tmp_path, body)
    chain = load_chain(path, "base_link", "tool0")
    assert chain.kinds == ("revolute", "prismatic", "continuous") and list(chain.prismatic) == [False, True, False]
    independent = yourdfpy.URDF.load(str(path), load_meshes=False, build_collision_scene_graph=False)
    joints = np.random.default_rng(5).uniform(np.maximum(chain.lower, -3), np.minimum(chain.upper, 3), (20, 3))
    for value in joints:
        independent.update_cfg(dict(zip(chain.joint_names, value, strict=True)))
        assert np.abs(chain.forward(value) - independent.get_transform("tool0", "base_link")).max() < 1e-12
    # every joint at once (motions) is each joint alone (motion), to the bit, whatever the batch's shape
    for shape in [(3,), (1, 3), (20, 3), (4, 5, 3)]:
        batch = joints.reshape(-1)[:int(np.prod(shape))].reshape(shape)
        for index in range(3):
            assert np.array_equal(chain.motion(index, batch[..., index]), chain.motions(batch)[..., index, :, :])
    frames = chain.frames(joints)
    current = np.broadcast_to(np.eye(4), (len(joints), 4, 4))
    for index in range(3):  # the chain's product, a joint at a time
        current = current @ chain.origins[index] @ chain.motion(index, joints[:, index])
        assert np.array_equal(frames[:, index], current)
    assert np.array_equal(frames[:, -1], current @ chain.origins[-1])
    assert np.allclose(jacobians(chain, frames), np.stack([chain.jacobian(value) for value in joints]), atol=1e-12)
