"""Shared fixtures and helpers: the same model in servodyn and in Pinocchio (the independent
oracle), and the command line run in this process (`cli`). helpers.py has the rest."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))


class PinocchioTwin:
    """A servodyn model exported to URDF and loaded by Pinocchio's own parser, with the map
    between the two joint orders (Pinocchio numbers joints depth-first, servodyn by body)."""

    def __init__(self, model, tmp_path: Path):
        import pinocchio as pin
        self.pin = pin
        path = tmp_path / f"{model.name}.urdf"
        model.to_urdf(path)
        if model.free_root:
            self.model = pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer())
        else:
            self.model = pin.buildModelFromUrdf(str(path))
        self.model.gravity.linear = np.asarray(model.gravity)
        assert self.model.nq == model.nq and self.model.nv == model.nv, "same coordinates"
        # Pinocchio's free-flyer has servodyn's order and frames: (x, y, z, quaternion), (v, w)
        hinge_names = model.dof_names[6:] if model.free_root else model.dof_names
        joints = [self.model.joints[self.model.getJointId(n)] for n in hinge_names]
        lead_q, lead_v = (list(range(7)), list(range(6))) if model.free_root else ([], [])
        self.index_q = np.array(lead_q + [j.idx_q for j in joints], dtype=int)
        self.index = np.array(lead_v + [j.idx_v for j in joints], dtype=int)
        # the Pinocchio joint that carries each servodyn body (its last dof; 1 for a free root)
        self.body_joint = [1 if b.free else self.model.getJointId(b.dofs[-1].name) if b.dofs else None
                           for b in model.bodies]
        self.set_armature(model.armature)

    def set_armature(self, armature):
        """Pinocchio's model.armature from servodyn-ordered values (URDF has none to carry it)."""
        self.model.armature = self.to_pin(armature)
        self.data = self.model.createData()

    def to_pin(self, x):
        out = np.zeros(len(self.index))
        out[self.index] = x
        return out

    def to_pin_q(self, q):
        out = np.zeros(len(self.index_q))
        out[self.index_q] = q
        return out

    def _call(self, algorithm, q, qd, x, f_ext):
        """Pinocchio's algorithm on servodyn-ordered arrays; wrenches go to each body's last joint."""
        args = [self.model, self.data, self.to_pin_q(q), self.to_pin(qd), self.to_pin(x)]
        if f_ext is not None:
            fext = [self.pin.Force.Zero() for _ in range(self.model.njoints)]
            for body, jid in enumerate(self.body_joint):
                assert jid is not None or not np.any(f_ext[body]), "welded bodies take no wrench here"
                if jid is not None:
                    fext[jid] = self.pin.Force(f_ext[body, 3:], f_ext[body, :3])
            args.append(fext)
        return algorithm(*args)[self.index]

    def rnea(self, q, qd, qdd, f_ext=None):
        return self._call(self.pin.rnea, q, qd, qdd, f_ext)

    def aba(self, q, qd, tau, f_ext=None):
        return self._call(self.pin.aba, q, qd, tau, f_ext)


@pytest.fixture
def twin(tmp_path):
    return lambda model: PinocchioTwin(model, tmp_path)


def rel_err(a, b) -> float:
    """max |a - b| relative to max |b| (floored at 1e-12 so exact zeros compare absolutely)."""
    a, b = np.asarray(a), np.asarray(b)
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-12))


def random_state(rng, model, scale_qd=2.0, scale_qdd=5.0):
    """A random (q, qd, qdd) inside the joint limits; a free root gets a random pose."""
    n = model.nv
    lo = np.maximum(model.lower, -3.0)
    hi = np.minimum(model.upper, 3.0)
    v = rng.uniform(lo, hi)
    if model.free_root:
        quat = rng.normal(size=4)
        q = np.concatenate([v[:3], quat / np.linalg.norm(quat), v[6:]])
    else:
        q = v
    return q, rng.normal(size=n) * scale_qd, rng.normal(size=n) * scale_qdd


def pinocchio_direct(model):
    """The model built joint by joint in Pinocchio (no URDF): a free-flyer for a free root, a
    spherical joint for a ball joint, revolute joints about the given axes otherwise. Joint
    order and coordinates then match servodyn's q and qd directly."""
    import pinocchio as pin
    pm = pin.Model()
    pm.gravity.linear = np.asarray(model.gravity)
    joint_of = {}
    for i, body in enumerate(model.bodies):
        parent = 0 if body.parent < 0 else joint_of[body.parent]
        placement = pin.SE3(np.asarray(body.rot, dtype=float), np.asarray(body.pos, dtype=float))
        if body.free:
            jid = pm.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), f"{body.name}_free")
        elif body.ball:
            jid = pm.addJoint(parent, pin.JointModelSpherical(), placement, f"{body.name}_ball")
        else:
            assert body.dofs, "welded bodies are not built here"
            jid = parent
            for k, dof in enumerate(body.dofs):
                axis = np.asarray(dof.axis, dtype=float) / np.linalg.norm(dof.axis)
                jid = pm.addJoint(jid, pin.JointModelRevoluteUnaligned(axis),
                                  placement if k == 0 else pin.SE3.Identity(), dof.name)
        pm.appendBodyToJoint(jid, pin.Inertia(body.mass, np.asarray(body.com, float),
                                              np.asarray(body.inertia, float)), pin.SE3.Identity())
        joint_of[i] = jid
    pm.armature = model.armature
    return pm


@pytest.fixture
def cli(capsys):
    """`servodyn ARGS...` run in this process (no interpreter to start: for the many short
    commands whose test needs no process of their own), as a CompletedProcess like run_cli's."""
    from servodyn.tools.cli import main

    def run(*args) -> subprocess.CompletedProcess:
        capsys.readouterr()
        argv = [str(a) for a in args]
        try:
            code = main(argv)
        except SystemExit as stop:         # argparse's refusals exit from inside main
            code = stop.code
        out, err = capsys.readouterr()
        return subprocess.CompletedProcess(argv, code, out, err)
    return run


# The slow tests of the two files being rewritten with the command line (test_cli.py and
# test_first_use.py), each over 20 s on a loaded 2-core machine: whole swings and validations,
# figures. Their @pytest.mark.slow belongs in those files; until then it is added here.
SLOW_ELSEWHERE = {
    "test_cli.py": {"test_demo_prints_the_torque_profile", "test_unwritable_output_gives_one_line",
                    "test_torques_refuses_a_trajectory_beyond_the_limits",
                    "test_unreadable_input_files_give_one_line_naming_the_file", "test_export_loads_in_pinocchio",
                    "test_bad_trajectories_give_one_line_and_exit_2",
                    "test_torques_derive_velocity_and_acceleration_from_a_spline"},
    "test_first_use.py": {"test_the_swings_figure_reads_at_a_glance",
                          "test_a_tiny_supply_voltage_is_refused_with_the_data_sheets_range",
                          "test_a_huge_position_in_the_validators_lines_is_readable",
                          "test_report_json_is_strict_and_names_what_is_not_finite",
                          "test_a_100k_character_name_is_cut_in_every_figure_title",
                          "test_a_refused_swing_is_one_line_and_verbose_lists_every_violation",
                          "test_no_numpy_warning_reaches_the_user",
                          "test_list_names_every_builtin_model_configuration_and_motion",
                          "test_a_port_that_does_not_open_is_one_line_and_no_run",
                          "test_a_count_that_makes_no_sense_is_refused_in_one_line"},
}


def pytest_collection_modifyitems(config, items):
    """The marks SLOW_ELSEWHERE lists. And a test marked serial is judged against the wall clock:
    never beside a parallel neighbour, so under a pytest-xdist worker it is skipped, saying where
    it runs (make test runs `-m serial` alone)."""
    worker = hasattr(config, "workerinput")
    alone = pytest.mark.skip(reason="serial: judged against the wall clock, run alone (pytest -m serial)")
    for item in items:
        if item.originalname in SLOW_ELSEWHERE.get(item.path.name, ()):
            item.add_marker(pytest.mark.slow)
        if worker and item.get_closest_marker("serial"):
            item.add_marker(alone)
