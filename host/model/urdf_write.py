"""A model written as URDF, with its solids as visual geometry, so Pinocchio, MuJoCo and RViz
see the same robot (`Model.to_urdf`); urdf.py reads one back."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .rotations import unit
from .shapes import box_sides, local_mesh

MUJOCO_EXTENSION = ('  <mujoco>\n    <compiler boundmass="1e-9" boundinertia="1e-12" fusestatic="false" '
                    'discardvisual="false"/>\n  </mujoco>\n')


def _visuals(body, path: Path, pose) -> list:
    """The body's solids as URDF visual geometry: cylinders, spheres and boxes as URDF's own, a
    frustum or an ellipsoid as a mesh (binary STL beside the URDF, named after it, the body and
    the solid), all in the body's user frame."""
    import trimesh
    from yourdfpy.urdf import Box, Cylinder, Geometry, Material, Mesh, Sphere, Visual, Color
    material = Material(name="solid", color=Color(rgba=np.array([0.72, 0.74, 0.78, 1.0])))
    visuals = []
    for k, solid in enumerate(body.solids):
        origin = pose(solid.rot, solid.pos)
        if solid.kind == "cylinder":
            # URDF's cylinder is centred on its origin; ours starts there
            origin = pose(solid.rot, solid.pos + solid.rot @ np.array([0.0, 0.0, solid.dims[1] / 2]))
            geometry = Geometry(cylinder=Cylinder(radius=solid.dims[0], length=solid.dims[1]))
        elif solid.kind == "sphere":
            geometry = Geometry(sphere=Sphere(radius=solid.dims[0]))
        elif solid.draw == "box":
            geometry = Geometry(box=Box(size=box_sides(solid)))
        else:
            name = f"{path.stem}__{body.name}__{k + 1}.stl"
            vertices, faces = local_mesh(solid)
            trimesh.Trimesh(vertices, faces, process=False).export(path.parent / name, file_type="stl")
            geometry = Geometry(mesh=Mesh(filename=name))
        visuals.append(Visual(name=f"{body.name}_{solid.kind}_{k + 1}", origin=origin, geometry=geometry,
                              material=material))
    return visuals


def write_urdf(model: "Model", path: str | Path) -> None:
    import yourdfpy
    from yourdfpy.urdf import Inertial, Joint, Limit, Link, Robot
    # a free root is the URDF's root link (load it with a floating base); otherwise "base" is
    links = [] if model.free_root else [Link(name="base")]
    joints = []

    def pose(R, p):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, p
        return T

    for body in model.bodies:
        parent = "base" if body.parent < 0 else model.bodies[body.parent].name
        visuals = _visuals(body, Path(path), pose)
        if body.free:
            links.append(Link(name=body.name, inertial=Inertial(origin=pose(np.eye(3), body.com),
                                                                mass=body.mass, inertia=body.inertia),
                              visuals=visuals))
            continue
        if not body.dofs:
            joints.append(Joint(name=f"{body.name}_weld", type="fixed", parent=parent, child=body.name,
                                origin=pose(body.rot @ body.post, body.pos)))
        for k, dof in enumerate(body.dofs):
            # the last dof's child is the body itself unless a fixed rotation still follows
            last = k == len(body.dofs) - 1
            child = body.name if last and np.allclose(body.post, np.eye(3)) else f"{body.name}__dof{k + 1}"
            origin = pose(body.rot, body.pos) if k == 0 else np.eye(4)
            bounded = math.isfinite(dof.lower) and math.isfinite(dof.upper)
            joints.append(Joint(name=dof.name, type="revolute" if bounded else "continuous",
                                parent=parent, child=child, origin=origin,
                                axis=unit(dof.axis),
                                limit=Limit(effort=1e3, velocity=1e3,
                                            lower=dof.lower if bounded else None,
                                            upper=dof.upper if bounded else None)))
            if child != body.name:
                links.append(Link(name=child))
            parent = child
        if body.dofs and parent != body.name:
            joints.append(Joint(name=f"{body.name}_post", type="fixed", parent=parent, child=body.name,
                                origin=pose(body.post, np.zeros(3))))
        links.append(Link(name=body.name, inertial=Inertial(origin=pose(np.eye(3), body.com),
                                                            mass=body.mass, inertia=body.inertia),
                          visuals=visuals))
    urdf = yourdfpy.URDF(robot=Robot(name=model.name, links=links, joints=joints),
                         build_scene_graph=False, load_meshes=False, mesh_dir=str(Path(path).parent))
    urdf.write_xml_file(str(path))
    # MuJoCo refuses massless moving bodies: its URDF extension lets the connector links between
    # the dofs of one joint carry a negligible bound mass instead (others ignore the element)
    text = Path(path).read_text()
    start = text.index("<robot")
    end = text.index(">", start) + 1
    text = text[:end] + "\n" + MUJOCO_EXTENSION.rstrip("\n") + text[end:]
    Path(path).write_text(text)

