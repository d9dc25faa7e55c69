"""Model building and validation (firmware/core/model.c, host/model/tree.py, host/model/modelfile.py,
host/model/urdf.py): built-in models, primitives, bad models, URDF in and out."""

import math
import textwrap
import threading

import numpy as np
import pytest

import servodyn
from servodyn import Body, Dof, Model, ModelError
from servodyn import _core
from servodyn.model.rotations import axis_angle, rpy_to_matrix


def test_builtin_models_have_the_papers_masses():
    """Fig. 2 mass fractions of a 70 kg body."""
    arm = servodyn.load_model("human_arm")
    assert arm.nq == 7 and len(arm.dof_names) == 7, "shoulder 3, elbow, pronation, wrist 2"
    masses = dict(zip(arm.body_names, (b.mass for b in arm.bodies)))
    assert masses == pytest.approx({"r_upper_arm": 0.028 * 70, "r_forearm": 0.016 * 70,
                                    "r_hand": 0.006 * 70}, rel=1e-12), "upper arm 2.8 %, forearm 1.6 %, hand 0.6 %"
    body = servodyn.load_model("human15")
    assert body.nbody == 15, "the paper's 15 segments"
    assert body.total_mass == pytest.approx(70.0, rel=1e-12), "the 15 fractions sum to one"
    assert np.allclose(body.gravity, [0.0, 0.0, -9.81]), "default gravity: 9.81 m/s² down world z"


def test_with_gravity_is_a_new_model():
    arm = servodyn.load_model("human_arm")
    q = np.full(arm.nq, 0.3)
    zero = np.zeros(arm.nq)
    tau = arm.inverse_dynamics(q, zero, zero)
    heavy = arm.with_gravity((0.0, 0.0, -2 * 9.81))
    assert np.allclose(heavy.inverse_dynamics(q, zero, zero), 2 * tau, rtol=1e-12), "static torque is linear in g"
    assert np.array_equal(arm.inverse_dynamics(q, zero, zero), tau), "the original model is unchanged"
    assert np.array_equal(arm.gravity, [0.0, 0.0, -9.81]), "the original keeps its gravity"
    with pytest.raises(ModelError, match="gravity"):
        arm.with_gravity((0.0, np.nan, 0.0))
    with pytest.raises(AttributeError):
        arm.gravity = (0.0, 0.0, 0.0)      # no setter: a Model does not change once built


@pytest.mark.parametrize("kind,dims,expected", [
    # closed forms about the centroid, m = 2 kg
    ("cylinder", (0.05, 0.3), (2 * (3 * 0.05**2 + 0.3**2) / 12, 2 * 0.05**2 / 2)),
    ("sphere", (0.05,), (0.4 * 2 * 0.05**2, 0.4 * 2 * 0.05**2)),
    ("ellipsoid", (0.05, 0.05, 0.1), (2 * (0.05**2 + 0.1**2) / 5, 2 * (2 * 0.05**2) / 5)),
    ("frustum", (0.05, 0.05, 0.3), (2 * (3 * 0.05**2 + 0.3**2) / 12, 2 * 0.05**2 / 2)),
])
def test_solid_primitives(kind, dims, expected):
    com_z, inertia = _core.solid_inertia(kind, 2.0, dims)
    assert inertia[0] == pytest.approx(expected[0], rel=1e-12), f"{kind}: transverse moment about the centroid"
    assert inertia[2] == pytest.approx(expected[1], rel=1e-12), f"{kind}: moment about the axis of symmetry (z)"


def test_frustum_by_slicing():
    """A frustum's centroid and moments against a numerical stack of 20000 thin discs."""
    r0, r1, length, mass = 0.053, 0.044, 0.3255, 1.96
    com_z, inertia = _core.solid_inertia("frustum", mass, (r0, r1, length))
    z = (np.arange(20000) + 0.5) / 20000 * length
    r = r0 + (r1 - r0) * z / length
    dm = r**2 / np.sum(r**2) * mass
    zc = np.sum(dm * z) / mass
    axial = np.sum(dm * r**2 / 2)
    transverse = np.sum(dm * (r**2 / 4 + (z - zc) ** 2))
    assert com_z == pytest.approx(zc, rel=1e-7), "centroid height against the stack of discs"
    assert inertia[2] == pytest.approx(axial, rel=1e-7), "axial moment: sum of dm r²/2 over the discs"
    assert inertia[0] == pytest.approx(transverse, rel=1e-7), \
        "transverse moment about the centroid: sum of dm (r²/4 + (z - zc)²)"


def one_body(**change):
    body = dict(name="link", parent=-1, pos=np.zeros(3), rot=np.eye(3), dofs=[Dof("j", np.array([0, 0, 1.0]))],
                mass=1.0, com=np.array([0.0, 0.0, 0.1]), inertia=np.diag([0.01, 0.01, 0.005]))
    body.update(change)
    return Body(**body)


@pytest.mark.parametrize("change,message", [
    (dict(mass=-1.0), "mass must be positive"),
    (dict(mass=0.0), "mass must be positive"),
    (dict(inertia=np.diag([0.01, 0.01, -0.005])), "positive definite"),
    (dict(inertia=np.diag([0.01, 0.001, 0.001])), "triangle inequality"),
    (dict(inertia=np.array([[0.01, 0.02, 0], [0.02, 0.01, 0], [0, 0, 0.01]])), "positive definite"),
    (dict(com=np.array([0.0, np.nan, 0.0])), "NaN or infinite"),
    (dict(pos=np.array([np.inf, 0.0, 0.0])), "NaN or infinite"),
    (dict(rot=np.diag([1.0, 1.0, -1.0])), "orthonormal"),
    (dict(dofs=[Dof(f"j{k}", np.array([0, 0, 1.0])) for k in range(4)]), "at most 3 dofs"),
    (dict(dofs=[Dof("j", np.zeros(3))]), "axis must be a finite non-zero"),
    (dict(dofs=[Dof("j", np.array([0, 0, 1.0]), 1.0, -1.0)]), "lower limit above upper"),
    (dict(parent=0), "parent must come before"),
])
def test_bad_models_are_refused_with_the_body_named(change, message):
    with pytest.raises(ModelError, match=message) as err:
        Model([one_body(**change)])
    assert "link" in str(err.value) or "'j" in str(err.value), f"neither body 'link' nor dof 'j' named: {err.value}"


def test_size_limits_are_checked():
    bodies = [one_body(name=f"b{i}", parent=i - 1, dofs=[Dof(f"j{i}", np.array([0, 0, 1.0]))])
              for i in range(_core.MAX_BODY + 1)]
    with pytest.raises(ModelError, match="1 to 128 bodies"):
        Model(bodies)


def test_duplicate_names_are_refused():
    with pytest.raises(ModelError, match="used twice"):
        Model([one_body(), one_body(parent=0)])


def write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


_DOF = "[[body]]\nname='a'\n[[body.dof]]\nname='j'\naxis=[0,0,1]\n{}\n[body.solid]\ntype='sphere'\nradius=0.1\nmass=1\n"


@pytest.mark.parametrize("text,message", [
    ("name = 'x'\n", "needs at least one"),
    ("[[body]]\nname='a'\nparent='nope'\n[body.solid]\ntype='sphere'\nradius=0.1\nmass=1\n", "parent 'nope'"),
    ("[[body]]\nname='a'\n[body.solid]\ntype='cube'\nradius=0.1\nmass=1\n", "'type' must be one of"),
    ("[[body]]\nname='a'\n[body.solid]\ntype='sphere'\nradius=-0.1\nmass=1\n", "dimensions must be positive"),
    ("[[body]]\nname='a'\n[body.solid]\ntype='sphere'\nradius=0.1\n", "exactly one of 'mass'"),
    ("[[body]]\nname='a'\n[body.solid]\ntype='sphere'\nradius=0.1\nmass_fraction=0.1\n", "total_mass"),
    ("[[body]]\nname='a'\npos=[0,0]\n[body.solid]\ntype='sphere'\nradius=0.1\nmass=1\n", "'pos' must be a list of 3"),
    ("[[body]]\nname='a'\n[[body.dof]]\nname='j'\n[body.solid]\ntype='sphere'\nradius=0.1\nmass=1\n", "'axis' must be"),
    ("[[body]]\nname='a'\n", "needs a \\[body.solid\\]"),
    ("[[body]\nname='a'\n", "not valid TOML"),
    # tables where a table belongs, found by the property tests (AttributeError, TypeError before)
    ("body = [1]\n", "body #1 must be a table"),
    ("[[body]]\nname='a'\ndof=[0]\n[body.solid]\ntype='sphere'\nradius=0.1\nmass=1\n", "dof #1 must be a table"),
    ("[[body]]\nname='a'\ndof=7\n[body.solid]\ntype='sphere'\nradius=0.1\nmass=1\n", "dof must be an array of tables"),
    ("[[body]]\nname='a'\nsolid=['x']\n", "solid #1 must be a table"),
    ("[[body]]\nname='a'\ninertial=2\n", "inertial must be a table"),
    ("[[body]]\nname='a'\nparent=[]\n[body.solid]\ntype='sphere'\nradius=0.1\nmass=1\n", "parent '\\[\\]' is not"),
    ("[[body]]\nname='a'\n[body.solid]\ntype=[]\nradius=0.1\nmass=1\n", "'type' must be one of"),
    # a dof's armature: its own, or its motor's, never both; a motor the parts list has with one
    (_DOF.format("armature=-0.1"), "dof 'j': the armature must be a finite number >= 0"),
    (_DOF.format("armature='big'"), "dof 'j': 'armature' must be a finite number"),
    (_DOF.format("motor='XM430-W351'"), "dof 'j': unknown motor 'XM430-W351' \\(parts with an armature: DM-J4340"),
    (_DOF.format("motor='DM-J4310'\narmature=0.2"), "dof 'j': give 'motor' or 'armature', not both"),
])
def test_bad_model_files_give_one_clear_line(tmp_path, text, message):
    path = write(tmp_path, "bad.toml", text)
    with pytest.raises(ModelError, match=message) as err:
        servodyn.load_model(path)
    assert "\n" not in str(err.value)


def test_a_dof_takes_its_armature_or_its_motors(tmp_path):
    """`armature` is the dof's own (kg m²); `motor` names a part whose armature it takes."""
    own = servodyn.load_model(write(tmp_path, "own.toml", _DOF.format("armature=0.02")))
    geared = servodyn.load_model(write(tmp_path, "geared.toml", _DOF.format("motor='DM-J4340'")))
    assert own.armature.tolist() == [0.02] and own.bodies[0].dofs[0].motor == "", "the dof's own"
    assert geared.armature.tolist() == [0.16] and geared.bodies[0].dofs[0].motor == "DM-J4340", \
        "the DM-J4340's 0.16 kg m² (parts.toml)"


def test_unknown_model_name():
    with pytest.raises(ModelError, match="not a built-in model"):
        servodyn.load_model("human_leg")
    # a name with a line break (found by the property tests through a configuration's 'model')
    with pytest.raises(ModelError, match=r"^'\\n': no such file") as err:
        servodyn.load_model("\n")
    assert "\n" not in str(err.value), "the error stays one line"


URDF_FEATURES = """\
<robot name="features">
  <link name="world"/>
  <link name="torso"><inertial><origin xyz="0 0 0.1" rpy="0 0 0"/><mass value="3"/>
    <inertia ixx="0.05" iyy="0.04" izz="0.03" ixy="0.001" ixz="0" iyz="0.002"/></inertial></link>
  <joint name="waist" type="continuous"><parent link="world"/><child link="torso"/>
    <origin xyz="0 0 1" rpy="0.1 0.2 0.3"/><axis xyz="0 0 1"/></joint>
  <link name="shoulder_a"/>
  <link name="shoulder_b"/>
  <link name="arm"><inertial><origin xyz="0 0 -0.15" rpy="0.3 0 0"/><mass value="2"/>
    <inertia ixx="0.02" iyy="0.02" izz="0.004" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="sh_x" type="revolute"><parent link="torso"/><child link="shoulder_a"/>
    <origin xyz="0 -0.2 0.3" rpy="0 0.4 0"/><axis xyz="1 0 0"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <joint name="sh_y" type="revolute"><parent link="shoulder_a"/><child link="shoulder_b"/>
    <origin xyz="0 0 0" rpy="0.5 0 0"/><axis xyz="0 0.6 0.8"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <joint name="sh_z" type="revolute"><parent link="shoulder_b"/><child link="arm"/>
    <origin xyz="0 0 0" rpy="0 0 0.7"/><axis xyz="0 0 1"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <link name="tool"><inertial><origin xyz="0 0 -0.05"/><mass value="0.5"/>
    <inertia ixx="0.001" iyy="0.001" izz="0.001" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="tool_mount" type="fixed"><parent link="arm"/><child link="tool"/>
    <origin xyz="0 0 -0.3" rpy="0 1.0 0"/></joint>
  <link name="finger"><inertial><mass value="0.1"/>
    <inertia ixx="0.0001" iyy="0.0001" izz="0.0001" ixy="0" ixz="0" iyz="0"/></inertial></link>
  <joint name="finger_joint" type="revolute"><parent link="tool"/><child link="finger"/>
    <origin xyz="0.02 0 -0.1" rpy="0 0 0"/><axis xyz="0 1 0"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
</robot>
"""


def test_urdf_import_groups_merges_and_matches_pinocchio(tmp_path):
    """A URDF with a continuous joint, a 3-revolute shoulder behind massless links with rotated
    origins and non-z axes, a fixed tool merged into the arm, and a joint on the fixed tool:
    servodyn's import and Pinocchio's own parser of the same file agree to 1e-9."""
    import pinocchio as pin
    path = write(tmp_path, "features.urdf", URDF_FEATURES)
    model = servodyn.load_model(path)
    assert model.dof_names == ("waist", "sh_x", "sh_y", "sh_z", "finger_joint"), \
        "the moving joints in tree order; the fixed tool_mount is no dof"
    assert [len(b.dofs) for b in model.bodies] == [1, 3, 1], "the shoulder is one 3-dof joint"
    assert model.bodies[1].mass == pytest.approx(2.5), "the fixed tool merged into the arm"
    pm = pin.buildModelFromUrdf(str(path))
    pd = pm.createData()
    rng = np.random.default_rng(1)
    for _ in range(20):
        q, qd, qdd = rng.uniform(-1.5, 1.5, 5), rng.normal(size=5), rng.normal(size=5)
        # Pinocchio's continuous joint takes (cos, sin)
        pq = np.concatenate([[math.cos(q[0]), math.sin(q[0])], q[1:]])
        tau_pin = pin.rnea(pm, pd, pq, qd, qdd)
        tau = model.inverse_dynamics(q, qd, qdd)
        assert np.abs(tau - tau_pin).max() <= 1e-9 * max(1.0, np.abs(tau_pin).max()), \
            "inverse dynamics differ from Pinocchio's parse of the same URDF"
        qdd_pin = pin.aba(pm, pd, pq, qd, tau)
        assert np.abs(model.forward_dynamics(q, qd, tau) - qdd_pin).max() <= 1e-9 * np.abs(qdd_pin).max(), \
            "forward dynamics differ from Pinocchio's parse of the same URDF"


def test_urdf_round_trip_keeps_the_dynamics(tmp_path):
    model = servodyn.load_model("human15")
    model.to_urdf(tmp_path / "h15.urdf")
    again = servodyn.load_model(tmp_path / "h15.urdf")
    assert again.dof_names == model.dof_names, "the export keeps every dof's name and order"
    rng = np.random.default_rng(2)
    q, qd, qdd = rng.normal(size=(3, model.nq))
    assert np.allclose(again.inverse_dynamics(q, qd, qdd), model.inverse_dynamics(q, qd, qdd),
                       rtol=1e-12, atol=1e-12), "inverse dynamics changed through URDF export and import"


@pytest.mark.parametrize("text,message", [
    ("<robot name='x'><link name='a'/></robot>", "no moving joint"),
    ("<robot name='x'><link name='a'/><link name='b'/></robot>", "exactly one root link"),
    ("<robot name='x'><link name='a'/><link name='b'><inertial><mass value='1'/><inertia ixx='1' iyy='1' izz='1' ixy='0' ixz='0' iyz='0'/></inertial></link>"
     "<joint name='p' type='prismatic'><parent link='a'/><child link='b'/><axis xyz='1 0 0'/><limit lower='0' upper='1' effort='1' velocity='1'/></joint></robot>", "not supported"),
    ("<robot name='x'><link name='a'/><link name='b'/>"
     "<joint name='j' type='continuous'><parent link='a'/><child link='b'/></joint></robot>", "positive mass"),
    ("this is not xml", "cannot read URDF"),
    # numbers a URDF may carry that no geometry can use (an SVD error, a shape error before)
    ("<robot name='x'><link name='a'/><link name='b'><inertial><mass value='1'/><inertia ixx='1' iyy='1' izz='1' ixy='0' ixz='0' iyz='0'/></inertial></link>"
     "<joint name='j' type='continuous'><origin xyz='0 0 0' rpy='nan 0 0'/><parent link='a'/><child link='b'/></joint></robot>",
     "joint 'j' <origin>: a NaN or infinite"),
    ("<robot name='x'><link name='a'/><link name='b'><inertial><mass value='1'/><inertia ixx='1' iyy='1' izz='1' ixy='0' ixz='0' iyz='0'/></inertial></link>"
     "<joint name='j' type='continuous'><axis xyz='nan'/><parent link='a'/><child link='b'/></joint></robot>",
     "joint 'j' <axis>: needs 3 numbers"),
    ("<robot name='x'><link name='a'/><link name='b'><inertial><mass value='inf'/><inertia ixx='1' iyy='1' izz='1' ixy='0' ixz='0' iyz='0'/></inertial></link>"
     "<joint name='j' type='continuous'><parent link='a'/><child link='b'/></joint></robot>",
     "link 'b' <inertial> <mass>: a NaN or infinite"),
])
def test_bad_urdf_gives_one_clear_line(tmp_path, text, message):
    path = write(tmp_path, "bad.urdf", text)
    with pytest.raises(ModelError, match=message) as err:
        servodyn.load_model(path)
    assert "\n" not in str(err.value)


def test_an_axis_of_any_finite_length_is_a_direction():
    """An axis is normalised without squaring it first: 1e300 (whose square overflows) points
    where 1 does; it once gave a NaN rotation and a misleading 'not orthonormal' error."""
    def arm(axis):
        body = one_body(dofs=[Dof("j", np.asarray(axis, dtype=float))])
        return Model([body, one_body(name="b", parent=0, dofs=[Dof("k", np.array([0, 1.0, 0]))])])
    q, qd, qdd = np.array([0.3, -0.2]), np.array([0.5, 1.0]), np.array([-1.0, 2.0])
    reference = arm([1.0, 1.0, 0.0]).inverse_dynamics(q, qd, qdd)
    for axis in ([1e300, 1e300, 0.0], [3.0, 3.0, 0.0], [1e308, 1e308, 0.0]):
        tau = arm(axis).inverse_dynamics(q, qd, qdd)
        assert np.allclose(tau, reference, rtol=1e-12, atol=1e-12), f"axis {axis} is not the direction (1, 1, 0)"


def test_multi_dof_axes_follow_each_other():
    """parent_R_body = rot · Rot(a1, q1) · Rot(a2, q2): the core's z-aligned dof frames reproduce
    the user-frame composition (checked through the world pose of the body's centre of mass)."""
    rng = np.random.default_rng(3)
    a1, a2 = rng.normal(size=3), rng.normal(size=3)
    rot = rpy_to_matrix(rng.normal(size=3))
    com = np.array([0.1, -0.05, 0.2])
    body = one_body(rot=rot, dofs=[Dof("j1", a1), Dof("j2", a2)], com=com)
    model = Model([body])
    q = np.array([0.7, -1.1])
    expected = rot @ axis_angle(a1, q[0]) @ axis_angle(a2, q[1]) @ com
    assert np.allclose(model.com_positions(q)[0], expected, atol=1e-14), \
        "centre of mass not where rot · Rot(a1, q1) · Rot(a2, q2) puts it"


def test_export_loads_in_mujoco(tmp_path):
    """MuJoCo refuses massless moving bodies; the export's MuJoCo extension bounds the connector
    links' mass at 1e-9 kg, so MuJoCo's inverse dynamics match servodyn's to 1e-7 relative."""
    import mujoco
    model = servodyn.load_model("human15")
    model.to_urdf(tmp_path / "h15.urdf")
    mj = mujoco.MjModel.from_xml_path(str(tmp_path / "h15.urdf"))
    mj.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT   # joint limits are no forces here
    data = mujoco.MjData(mj)
    names = [mj.joint(j).name for j in range(mj.njnt)]
    order = np.array([names.index(n) for n in model.dof_names])   # MuJoCo's qpos order per dof
    rng = np.random.default_rng(4)
    for _ in range(10):
        q, qd, qdd = rng.uniform(-1, 1, model.nq), rng.normal(size=model.nq), rng.normal(size=model.nq)
        data.qpos[order], data.qvel[order], data.qacc[order] = q, qd, qdd
        mujoco.mj_inverse(mj, data)
        tau = model.inverse_dynamics(q, qd, qdd)
        assert np.abs(data.qfrc_inverse[order] - tau).max() <= 1e-7 * np.abs(tau).max(), \
            "MuJoCo's inverse dynamics of the export (connectors at 1e-9 kg) differ from servodyn's"


BINARY = bytes(range(256)) * 4     # not UTF-8, not XML


@pytest.mark.parametrize("name,make,words", [
    ("m.toml", lambda p: p.write_bytes(BINARY), ["m.toml", "not a text file"]),
    ("m.toml", lambda p: p.mkdir(), ["m.toml", "is a folder"]),
    ("m.urdf", lambda p: p.write_bytes(BINARY), ["m.urdf", "cannot read URDF", "not XML"]),
    ("m.urdf", lambda p: p.write_text("garbage <robot"), ["m.urdf", "cannot read URDF", "not XML"]),
    ("m.urdf", lambda p: p.write_text("<mujoco/>"), ["m.urdf", "<mujoco>, not <robot>"]),
    ("m.urdf", lambda p: p.mkdir(), ["m.urdf", "is a folder"]),
])
def test_unreadable_model_files_are_one_model_error_naming_the_file(tmp_path, name, make, words):
    path = tmp_path / name
    make(path)
    with pytest.raises(ModelError) as err:
        servodyn.load_model(path)
    message = str(err.value)
    assert "\n" not in message and message.startswith(str(path)), message
    for word in words:
        assert word in message, f"{word!r} not in: {message}"


def _urdf(links, joints):
    inertial = ('<inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" '
                'iyz="0"/></inertial>')
    body = "".join(f'<link name="{n}">{inertial}</link>' for n in links)
    body += "".join(f'<joint name="{n}" type="{kind}"><parent link="{p}"/><child link="{c}"/>'
                    '<origin xyz="0 0 0.1"/><axis xyz="0 1 0"/></joint>' for n, kind, p, c in joints)
    return f'<robot name="r">{body}</robot>'


def test_urdf_loops_are_refused_by_name(tmp_path):
    """A loop of joints is not a tree: a link with two parents, or a loop hanging from nothing."""
    (tmp_path / "two_parents.urdf").write_text(_urdf(
        ["base", "a", "b"], [("j1", "continuous", "base", "a"), ("j2", "continuous", "a", "b"),
                             ("j3", "continuous", "b", "a")]))
    with pytest.raises(ModelError, match="link 'a' is the child of both joint 'j1' and joint 'j3'"):
        servodyn.load_model(tmp_path / "two_parents.urdf")
    (tmp_path / "island.urdf").write_text(_urdf(
        ["base", "a", "b", "c"], [("j1", "continuous", "base", "a"), ("j2", "continuous", "b", "c"),
                                  ("j3", "continuous", "c", "b")]))
    with pytest.raises(ModelError, match="island.urdf: link 'b' is not reached from the root 'base'"):
        servodyn.load_model(tmp_path / "island.urdf")


def test_long_urdf_chains_load_without_recursion(tmp_path):
    """The tree walk keeps its own stack: 120 hinges with a fixed joint between each (240 links
    deep, past Python's recursion limit at the old two frames a link) load in order; 500 joints
    are refused by the core's body limit, in one line naming the file."""
    def chain(n):
        links = ["base"] + [f"l{i}" for i in range(n)]
        joints = [(f"j{i}", "fixed" if i % 2 else "continuous", links[i], links[i + 1]) for i in range(n)]
        return _urdf(links, joints)
    (tmp_path / "chain.urdf").write_text(chain(240))
    model = servodyn.load_model(tmp_path / "chain.urdf")
    assert model.nq == 120 and model.dof_names[:2] == ("j0", "j2"), "one body per hinge, root first"
    assert model.bodies[-1].parent == 118, "a chain: each body hangs from the one before"
    (tmp_path / "long.urdf").write_text(chain(500))
    with pytest.raises(ModelError, match=r"long.urdf: a model needs 1 to \d+ bodies, got 250"):
        servodyn.load_model(tmp_path / "long.urdf")


def test_mass_scale_scales_every_rigid_body_torque():
    """with_mass_scale(1.2): every body's mass and inertia x 1.2, so every rigid-body torque (gravity,
    inertia, velocity products) x 1.2 exactly (1e-12 relative) while the armature's share stays;
    a scale <= 0 is refused in one line."""
    model = servodyn.load_model("replica")
    scaled = model.with_mass_scale(1.2)
    rng = np.random.default_rng(7)
    q = rng.uniform(model.lower, model.upper, (20, model.nq))
    qd, qdd = rng.uniform(-2, 2, (2, 20, model.nv))
    armature = model.armature * qdd
    expected = 1.2 * (model.inverse_dynamics(q, qd, qdd) - armature) + armature
    assert np.allclose(scaled.inverse_dynamics(q, qd, qdd), expected, rtol=1e-12, atol=1e-12)
    assert scaled.total_mass == pytest.approx(1.2 * model.total_mass, rel=1e-14)
    with pytest.raises(ModelError, match="mass scale must be a finite number > 0, got 0"):
        model.with_mass_scale(0.0)


def test_mass_matrix_is_pinocchios_crba_and_changes_nothing(twin):
    """M(q) equals Pinocchio's CRBA (to 1e-9 relative, a few ulps of sums of products) on the
    built-in models under a doubled and a sideways gravity, which must not leak into M. A thread
    computing M(q) 2,000 times leaves the model's gravity and its static torques untouched, as read
    meanwhile from this thread (a simulator's real-time thread steps the same Model object)."""
    rng = np.random.default_rng(5)
    for name in ("human_arm", "replica", "replica_dm"):
        for g in ((0.0, 0.0, -2 * 9.81), (3.0, -4.0, 0.0)):
            model = servodyn.load_model(name).with_gravity(g)
            pin = twin(model)
            q = rng.uniform(model.lower, model.upper)
            M = pin.pin.crba(pin.model, pin.data, pin.to_pin_q(q))
            M = np.triu(M) + np.triu(M, 1).T
            expected = M[np.ix_(pin.index, pin.index)]
            assert np.max(np.abs(model.mass_matrix(q) - expected)) <= 1e-9 * np.max(np.abs(expected)), \
                f"{name}, g = {g}: M(q) is the CRBA's, gravity plays no part"
    arm = servodyn.load_model("human_arm")
    q, zero = np.full(arm.nq, 0.3), np.zeros(arm.nq)
    tau = arm.inverse_dynamics(q, zero, zero)
    done = threading.Event()

    def masses():
        for _ in range(2000):
            arm.mass_matrix(q)
        done.set()

    worker = threading.Thread(target=masses)
    worker.start()
    reads = changed = 0
    while not done.is_set():
        reads += 1
        changed += not (np.array_equal(arm.gravity, [0.0, 0.0, -9.81])
                        and np.array_equal(arm.inverse_dynamics(q, zero, zero), tau))
    worker.join()
    assert reads > 0 and changed == 0, f"{changed} of {reads} reads saw the model changed during M(q)"
