"""URDF in and out, through yourdfpy.

In: a revolute or continuous joint is one dof named after the joint; a fixed joint merges its
child link into the parent body; consecutive revolute joints whose origins coincide, with
massless links between them, form one multi-dof joint (paper Fig. 3). The root link is the fixed
base. Out: one revolute joint per dof, with massless links between the dofs of one joint.
URDF has no armature (a geared motor's reflected rotor inertia): a URDF's dofs get none, and a
model's is not written (Pinocchio and MuJoCo set theirs apart: `model.armature`, `<joint armature>`).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .tree import Body, Dof, Model, ModelError, combine
from .rotations import orthonormalize

MASSLESS = 1e-12   # kg: below this a link is a connector between the dofs of one joint


def _finite(values, where: str, shape: tuple | None = None) -> np.ndarray:
    """The numbers of a URDF element, or a ModelError naming it: a NaN, an infinity or a missing
    number read from the file would otherwise reach the geometry (an SVD that does not converge,
    a silent NaN, a shape error)."""
    array = np.asarray(values, dtype=float)
    if shape is not None and array.shape != shape:
        raise ModelError(f"{where}: needs {' x '.join(map(str, shape))} numbers, got {array.size}")
    if not np.all(np.isfinite(array)):
        raise ModelError(f"{where}: a NaN or infinite number")
    return array


def _inertial(link):
    """(mass, com, inertia about com) of a URDF link in the link frame."""
    inertial = link.inertial
    if inertial is None or not inertial.mass:
        return 0.0, np.zeros(3), np.zeros((3, 3))
    where = f"link '{link.name}' <inertial>"
    T = np.eye(4) if inertial.origin is None else _finite(inertial.origin, f"{where} <origin>", (4, 4))
    R = T[:3, :3]
    I = np.zeros((3, 3)) if inertial.inertia is None else _finite(inertial.inertia, f"{where} <inertia>", (3, 3))
    return float(_finite(inertial.mass, f"{where} <mass>")), T[:3, 3].copy(), R @ I @ R.T


def _moved(part, R, p):
    mass, com, inertia = part
    return mass, R @ com + p, R @ inertia @ R.T


def _read_robot(path: Path):
    """yourdfpy's robot of a URDF file, or a ModelError naming the file. The file is read and
    parsed here first: yourdfpy logs a parse error and then fails with an unrelated TypeError."""
    import logging
    import xml.etree.ElementTree as ET
    import yourdfpy
    try:
        root = ET.fromstring(path.read_bytes())
    except IsADirectoryError:
        raise ModelError(f"{path}: is a folder, not a URDF file") from None
    except OSError as err:
        raise ModelError(f"{path}: cannot read ({err.strerror or err})") from None
    except ET.ParseError as err:
        raise ModelError(f"{path}: cannot read URDF (not XML: {err})") from None
    if root.tag != "robot":
        raise ModelError(f"{path}: cannot read URDF (the top element is <{root.tag}>, not <robot>)")
    logger = logging.getLogger("yourdfpy")
    level = logger.level
    logger.setLevel(logging.CRITICAL)     # its errors become ours, in one line
    try:
        return yourdfpy.URDF.load(str(path), build_scene_graph=False, load_meshes=False,
                                  build_collision_scene_graph=False, load_collision_meshes=False).robot
    except Exception as err:  # yourdfpy raises many kinds; all mean "not a usable URDF"
        raise ModelError(f"{path}: cannot read URDF ({type(err).__name__}: {err})") from None
    finally:
        logger.setLevel(level)


def _check_tree(path, root: str, children: dict, links: dict) -> None:
    """Every link hangs from the root (each already has at most one parent joint): a loop of
    joints would otherwise be left out, or walked forever."""
    seen, stack = {root}, [root]
    while stack:
        for joint in children[stack.pop()]:
            seen.add(joint.child)
            stack.append(joint.child)
    detached = [name for name in links if name not in seen]
    if detached:
        raise ModelError(f"{path}: link '{detached[0]}' is not reached from the root '{root}' (a loop of "
                         "joints with no way in)")


def load_urdf(path: str | Path, free_root: bool = False) -> Model:
    """A model from a URDF file; with free_root the root link floats free (6 dofs) instead of
    being the fixed base."""
    robot = _read_robot(Path(path))
    links = {link.name: link for link in robot.links}
    children: dict[str, list] = {name: [] for name in links}
    parent_joint: dict[str, str] = {}
    for joint in robot.joints:
        if joint.parent not in links or joint.child not in links:
            raise ModelError(f"joint '{joint.name}': links '{joint.parent}' or '{joint.child}' do not exist")
        if joint.child in parent_joint:
            raise ModelError(f"{path}: link '{joint.child}' is the child of both joint "
                             f"'{parent_joint[joint.child]}' and joint '{joint.name}' (a URDF is a tree)")
        children[joint.parent].append(joint)
        parent_joint[joint.child] = joint.name
    roots = [name for name in links if name not in parent_joint]
    if len(roots) != 1:
        raise ModelError(f"{path}: a URDF needs exactly one root link, found {roots}")
    _check_tree(path, roots[0], children, links)

    bodies: list[Body] = []
    parts: dict[int, list] = {}

    def origin(joint):
        T = np.eye(4) if joint.origin is None else _finite(joint.origin, f"joint '{joint.name}' <origin>", (4, 4))
        return orthonormalize(T[:3, :3]), T[:3, 3].copy()

    def attach(link_name, body, R, p):
        """Merge a link (at R, p in the body frame) and its fixed descendants into body; start
        new bodies at its moving joints. Depth first in file order (a parent's body before its
        children's), on a stack of its own: a chain of any length, not Python's recursion limit."""
        stack = [("link", link_name, body, R, p)]
        while stack:
            kind, item, body, R, p = stack.pop()
            if kind == "joint":
                link, index = start_joint(item, body, R, p)
                stack.append(("link", link, index, np.eye(3), np.zeros(3)))
                continue
            if body >= 0:
                parts[body].append(_moved(_inertial(links[item]), R, p))
            for joint in reversed(children[item]):
                Rj, pj = origin(joint)
                R_child, p_child = R @ Rj, R @ pj + p
                if joint.type == "fixed":
                    stack.append(("link", joint.child, body, R_child, p_child))
                elif joint.type in ("revolute", "continuous"):
                    stack.append(("joint", joint, body, R_child, p_child))
                else:
                    raise ModelError(f"joint '{joint.name}': type '{joint.type}' is not supported "
                                     "(servodyn joints are rotational: revolute, continuous, fixed)")

    def start_joint(joint, parent, R0, p0):
        """A body whose joint begins with `joint`; absorb following revolute joints at the same
        origin behind massless links into the same multi-dof joint. Returns its last link and
        the body's index."""
        dofs, post = [], np.eye(3)
        while True:
            axis = (np.array([1.0, 0.0, 0.0]) if joint.axis is None
                    else _finite(joint.axis, f"joint '{joint.name}' <axis>", (3,)))
            lower, upper = -math.inf, math.inf
            if joint.type == "revolute" and joint.limit is not None:
                lower = -math.inf if joint.limit.lower is None else float(joint.limit.lower)
                upper = math.inf if joint.limit.upper is None else float(joint.limit.upper)
            # an axis behind the fixed rotation P of the connectors moves in front of it: P Rot(a) = Rot(P a) P
            dofs.append(Dof(joint.name, post @ axis, lower, upper))
            link = joint.child
            nxt = children[link]
            if (len(dofs) < 3 and _inertial(links[link])[0] < MASSLESS and len(nxt) == 1
                    and nxt[0].type in ("revolute", "continuous")
                    and np.allclose(origin(nxt[0])[1], 0.0, atol=1e-12)):
                joint = nxt[0]
                post = post @ origin(joint)[0]
                continue
            break
        index = len(bodies)
        bodies.append(Body(name=link, parent=parent, pos=p0, rot=R0, dofs=dofs, post=post))
        parts[index] = []
        return link, index

    if free_root:
        # the root link is body 0, floating free; its inertia and fixed children move with it
        bodies.append(Body(name=roots[0], parent=-1, pos=np.zeros(3), rot=np.eye(3), free=True))
        parts[0] = []
        attach(roots[0], 0, np.eye(3), np.zeros(3))
    else:
        # the root link is the base; its own inertia does not move
        attach(roots[0], -1, np.eye(3), np.zeros(3))
    if not bodies:
        raise ModelError(f"{path}: the URDF has no moving joint")
    for index, body in enumerate(bodies):
        body.mass, body.com, body.inertia = combine(parts[index])
        if body.mass <= 0:
            raise ModelError(f"link '{body.name}': a moving link needs a positive mass")
    return Model(bodies, name=robot.name or path.stem)
