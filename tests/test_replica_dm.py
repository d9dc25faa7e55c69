"""The replica arm's models for the Damiao builds (replica_dm: DM-J4340 at the shoulder and elbow,
DM-J4310 at pronation and wrist; replica_mixed: the J4340s with XM430 servos from the forearm
out): their bodies against Pinocchio's own inertia of the same solids, their masses against the
sum of their parts from the data sheets (host/model/parts.toml), the motor housings drawn as the
cylinders the dynamics uses, and no housing inside another at any pose."""

from __future__ import annotations

import itertools
import math
import re

import numpy as np
import pytest
import trimesh

import servodyn
from servodyn.model.modelfile import ModelError, model_from_dict, parts
from servodyn.model.shapes import box_sides, local_mesh

BUILDS = ["replica_dm", "replica_mixed"]
# the motor at each dof, in dof order (the configurations replica_can and replica_mixed drive them)
MOTORS = {"replica_dm": ["DM-J4340"] * 4 + ["DM-J4310"] * 3,
          "replica_mixed": ["DM-J4340"] * 4 + ["XM430-W350"] * 3,
          "replica": ["XM540-W270"] * 3 + ["XM430-W350"] * 4}


def _housings(model):
    """(body index, solid, part name) of every actuator housing: a solid of a part's mass and size.
    Parts of one case and mass (the X430 family's XM430-W350, -W210, XH430-W350, ...) are one
    housing: the name is the first of them in the catalogue, the one the built-in models use."""
    catalogue = parts()
    found = []
    for i, body in enumerate(model.bodies):
        for solid in body.solids:
            for name, part in catalogue.items():
                dims = part.get("semi_axes") or [part[k] for k in ("radius", "length") if k in part]
                if solid.mass == part["mass"] and np.allclose(sorted(solid.dims), sorted(dims), rtol=0, atol=1e-12):
                    found.append((i, solid, name))
                    break
    return found


@pytest.mark.parametrize("name", BUILDS + ["replica"])
def test_bodies_are_pinocchios_sum_of_their_solids(name):
    """Each body's mass, centre of mass and inertia are those Pinocchio gives for its solids
    (pin.Inertia.FromCylinder / FromEllipsoid, placed by SE3 and added): the model file's
    composition (parallel axes, rotated solids, parts) checked against an independent library."""
    import pinocchio as pin
    model = servodyn.load_model(name)
    for body in model.bodies:
        total = pin.Inertia.Zero()
        for s in body.solids:
            if s.kind == "cylinder":
                radius, length = s.dims
                own = pin.Inertia.FromCylinder(s.mass, radius, length)
                centre = s.pos + s.rot @ np.array([0.0, 0.0, length / 2])   # ours runs along +z from pos
            else:
                assert s.kind == "ellipsoid", f"{body.name}: only cylinders and ellipsoids here"
                own = pin.Inertia.FromEllipsoid(s.mass, *s.dims)
                centre = s.pos
            total += pin.SE3(s.rot, centre).act(own)
        assert body.mass == pytest.approx(total.mass, rel=1e-12), f"{name} {body.name}: mass"
        assert np.allclose(body.com, total.lever, atol=1e-12), f"{name} {body.name}: centre of mass"
        assert np.allclose(body.inertia, total.inertia, rtol=0, atol=1e-9 * np.abs(total.inertia).max()), \
            f"{name} {body.name}: inertia about the centre of mass differs from Pinocchio's"


@pytest.mark.parametrize("name", BUILDS)
def test_same_dofs_and_segments_as_the_replica(name):
    """Same dof names, order, axes and limits as replica (so its motions play), and the same
    joint origins: upper arm 0.30 m, forearm 0.25 m."""
    model, replica = servodyn.load_model(name), servodyn.load_model("replica")
    assert model.dof_names == replica.dof_names, "same dofs in the same order"
    assert np.array_equal(model.lower, replica.lower) and np.array_equal(model.upper, replica.upper), "same limits"
    axes = lambda m: [d.axis for b in m.bodies for d in b.dofs]
    assert all(np.array_equal(a, b) for a, b in zip(axes(model), axes(replica))), "same axes"
    for q in np.random.default_rng(3).uniform(model.lower, model.upper, size=(20, 7)):
        assert np.allclose(model.body_poses(q)[1], replica.body_poses(q)[1], atol=1e-12), "same joint origins"


@pytest.mark.parametrize("name", BUILDS + ["replica"])
def test_each_motor_is_its_data_sheets_solid(name):
    """One housing per moving actuator (S2..S7; S1 is on the torso), each the part the
    configuration drives at that dof, with the manual's mass (362 g for a DM-J4340, 300 g for a
    DM-J4310), on the parent side of the dof it drives: S(k+1) sits on body k."""
    model = servodyn.load_model(name)
    housings = _housings(model)
    assert [(i, part) for i, _, part in housings] == [(k, MOTORS[name][k + 1]) for k in range(6)], \
        f"{name}: the housings by body: {[(i, p) for i, _, p in housings]}"
    assert parts()["DM-J4340"]["mass"] == 0.362 and parts()["DM-J4310"]["mass"] == 0.300, \
        "the manuals' figures: about 362 g and about 300 g"


def _described_masses(model) -> dict[str, float]:
    """'name mass' pairs the description lists, and its 'moving arm' total."""
    text = model.description
    listed = {k: float(v) for k, v in re.findall(r"(r_\w+) (\d\.\d{3})", text)}
    listed["moving arm"] = float(re.search(r"moving arm (\d\.\d{3})", text).group(1))
    return listed


@pytest.mark.parametrize("name, motors, total", [("replica_dm", 3 * 0.362 + 3 * 0.300, 2.510),
                                                 ("replica_mixed", 3 * 0.362 + 3 * 0.082, 1.785)])
def test_masses_are_the_sum_of_the_parts(name, motors, total):
    """The moving arm weighs its six moving actuators (data sheets) plus its structure (in
    replica_dm all aluminium: density 2700 kg/m^3 over the sizes in the file, or a tube's mass per
    metre); each body and the total are what the description says, to the gram it is written in."""
    model = servodyn.load_model(name)
    housings = sum(s.mass for _, s, _ in _housings(model))
    assert housings == pytest.approx(motors, abs=1e-12), f"{name}: the six moving actuators' masses"
    structure = [s for b in model.bodies for s in b.solids if s.mass not in [p["mass"] for p in parts().values()]]
    assert model.total_mass == pytest.approx(housings + sum(s.mass for s in structure), abs=1e-12), \
        "every solid is a housing or structure"
    for s in structure if name == "replica_dm" else []:     # replica_mixed's wrist and hand are replica's
        volume = math.pi * s.dims[0] ** 2 * s.dims[1]
        density = s.mass / volume
        tube = 0.39019 * s.dims[1] if abs(s.dims[0] - 0.016325) < 1e-9 else 0.23538 * s.dims[1]
        assert density == pytest.approx(2700.0, rel=1e-9) or s.mass == pytest.approx(tube, rel=1e-4), \
            f"{name}: a structural solid of {s.mass:.4f} kg is neither aluminium plate nor tube"
    assert model.total_mass == pytest.approx(total, abs=5e-4), f"{name}: {model.total_mass:.4f} kg of moving arm"
    described = _described_masses(model)
    assert described["moving arm"] == pytest.approx(model.total_mass, abs=5e-4), "the description's total"
    for body in model.bodies:
        assert described[body.name] == pytest.approx(body.mass, abs=5e-4), f"{name} {body.name}: the description's mass"


def test_the_damiao_arm_is_heavier_where_the_motors_are():
    """The same forehand needs the torques of the arm that is there: in the hanging pose the
    bodies' inertia about the shoulder flexion (its M_ii without the motors' rotors, the armature)
    is about 2.8x the Dynamixel replica's, about the elbow 2.6x; with the rotors, whose armature
    (parts.toml) the J4340 has larger too, 1.9x and 3.3x."""
    q0 = np.zeros(7)
    models = [servodyn.load_model(n) for n in ("replica", "replica_dm")]
    light, heavy = (np.diag(m.mass_matrix(q0)) - m.armature for m in models)
    assert heavy[0] / light[0] == pytest.approx(2.83, abs=0.05), f"shoulder flexion {heavy[0]:.4f} vs {light[0]:.4f}"
    assert heavy[3] / light[3] == pytest.approx(2.59, abs=0.05), f"elbow flexion {heavy[3]:.4f} vs {light[3]:.4f}"
    light, heavy = (np.diag(m.mass_matrix(q0)) for m in models)
    assert heavy[0] / light[0] == pytest.approx(1.92, abs=0.05), f"with rotors: {heavy[0]:.4f} vs {light[0]:.4f}"
    assert heavy[3] / light[3] == pytest.approx(3.25, abs=0.05), f"with rotors: {heavy[3]:.4f} vs {light[3]:.4f}"


@pytest.mark.parametrize("name", BUILDS)
def test_a_round_housing_drawn_has_the_inertia_the_dynamics_uses(name):
    """The browser view and the URDF draw each motor as the cylinder its inertia is: that mesh,
    at the motor's mass, has the cylinder's inertia m (3r^2 + L^2)/12 across and m r^2/2 along
    the shaft (trimesh integrates it; 192 segments leave 0.02 %), and its centroid at half length."""
    cylinders = [s for _, s, part in _housings(servodyn.load_model(name)) if part.startswith("DM-")]
    assert len(cylinders) == {"replica_dm": 6, "replica_mixed": 3}[name], "the moving Damiao motors"
    for solid in cylinders:
        mesh = trimesh.Trimesh(*local_mesh(solid, segments=192), process=False)
        mesh.density = solid.mass / mesh.volume
        r, length = solid.dims
        across = solid.mass * (3 * r * r + length * length) / 12
        assert np.allclose(np.diag(mesh.moment_inertia), [across, across, solid.mass * r * r / 2], rtol=5e-4), \
            "the drawn cylinder and the modelled one differ in inertia"
        assert np.allclose(mesh.center_mass, [0.0, 0.0, length / 2], atol=1e-9), "centroid halfway along the shaft"


def _inside(points, solid, margin: float) -> np.ndarray:
    """Which points (in the solid's body frame) lie inside the solid, `margin` in from its faces."""
    local = (points - solid.pos) @ solid.rot
    if solid.kind == "cylinder":
        r, length = solid.dims
        return ((np.hypot(local[:, 0], local[:, 1]) < r - margin) & (local[:, 2] > margin)
                & (local[:, 2] < length - margin))
    return np.all(np.abs(local) < box_sides(solid) / 2 - margin, axis=1)


# replica's wrist (replica.toml, which replica_mixed takes): its deviation servo S7, beside the
# wrist, swings into the flexion servo S6 at wrist flexion below about -0.6 rad
REPLICA_WRIST = {("r_forearm", "r_wrist_link")}


@pytest.mark.parametrize("name, known", [("replica_dm", set()), ("replica_mixed", REPLICA_WRIST)])
def test_no_housing_is_inside_another_at_any_pose(name, known):
    """Points filling each housing (its mesh's vertices and a grid inside it), carried by forward
    kinematics to 300 random poses within the joint limits and to the 32 corners of the shoulder's,
    elbow's and wrist flexion's ranges: none lies 0.5 mm or more inside another housing (but for
    the pair replica_mixed keeps from replica)."""
    model = servodyn.load_model(name)
    housings = _housings(model)
    pair = lambda i, j: tuple(sorted((model.bodies[i].name, model.bodies[j].name), key=model.body_names.index))
    clouds = []
    for _, solid, _ in housings:
        V, _ = local_mesh(solid, segments=48)
        lo, hi = V.min(axis=0), V.max(axis=0)
        grid = lo + np.stack(np.meshgrid(*[np.linspace(0, 1, 9)] * 3), axis=-1).reshape(-1, 3) * (hi - lo)
        cloud = np.vstack([V, grid]) @ solid.rot.T + solid.pos
        clouds.append(cloud[_inside(cloud, solid, -1e-9)])
    corners = []
    for pick in itertools.product(*[(model.lower[k], model.upper[k]) for k in (0, 1, 2, 3, 5)]):
        q = np.zeros(7)
        q[[0, 1, 2, 3, 5]] = pick
        corners.append(q)
    poses = list(np.random.default_rng(11).uniform(model.lower, model.upper, size=(300, 7))) + corners
    for q in poses:
        R, p = model.user_poses(q)
        world = [clouds[k] @ R[i].T + p[i] for k, (i, _, _) in enumerate(housings)]
        for a, (i, _, pa) in enumerate(housings):
            for b, (j, sb, pb) in enumerate(housings):
                if a != b and pair(i, j) not in known and _inside((world[a] - p[j]) @ R[j], sb, 5e-4).any():
                    raise AssertionError(f"{name}: {pa} on {model.bodies[i].name} reaches inside {pb} on "
                                         f"{model.bodies[j].name} at q = {np.round(q, 3).tolist()}")


def test_a_body_taken_from_another_file_and_a_part(tmp_path):
    """`from` copies a body of another model file (a built-in name or a path beside this file),
    its own keys in place; `part` places a catalogue part and refuses its own size or mass; a
    missing body, an unknown part and a circle of files are one-line errors naming them."""
    model = model_from_dict({"body": [{"name": "r_shoulder_pitch_link", "from": "replica_dm"},
                                      {"name": "r_shoulder_roll_link", "from": "replica_dm", "pos": [0.0, 0.0, -0.1]}]})
    dm = servodyn.load_model("replica_dm")
    assert model.bodies[0].mass == dm.bodies[0].mass and np.array_equal(model.bodies[1].inertia, dm.bodies[1].inertia), \
        "the bodies as replica_dm has them"
    assert np.array_equal(model.bodies[1].pos, [0.0, 0.0, -0.1]), "a key given here takes the place of the other file's"
    (tmp_path / "a.toml").write_text('[[body]]\nname = "x"\nfrom = "b.toml"\n')
    (tmp_path / "b.toml").write_text('[[body]]\nname = "x"\nfrom = "a.toml"\n')
    for body, words in [({"name": "nope", "from": "replica_dm"}, "replica_dm has no body 'nope'"),
                        ({"name": "x", "from": "missing.toml"}, "neither a built-in model"),
                        ({"name": "x", "from": "a.toml"}, "goes round in a circle"),
                        ({"name": "x", "solid": {"part": "DM-J9999"}}, "unknown part 'DM-J9999'"),
                        ({"name": "x", "solid": {"part": "DM-J4340", "mass": 1.0}}, "give it only pos and rpy, not mass")]:
        with pytest.raises(ModelError, match=re.escape(words)) as err:
            model_from_dict({"body": [body]}, folder=tmp_path)
        assert "\n" not in str(err.value), str(err.value)
