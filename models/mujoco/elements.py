"""MJCF building blocks shared by the generators.

Number formatting, quaternions, the body tree in MJCF order, body elements and the pretty
printer; body poses in fb.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import mujoco
import numpy as np

from models.description import Loop, Machine
from models.errors import ModelError
from models.mujoco.constants import JOINT_TYPE
from models.rotations import axis_rotation


def fmt(values) -> str:
    """Numbers as MJCF text, shortest exact form (MuJoCo's own writer keeps 6 digits)."""
    return " ".join(repr(float(v)) for v in np.atleast_1d(np.asarray(values, float)))


def quat(rotation: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation matrix."""
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.ascontiguousarray(rotation, dtype=float).reshape(9))
    return q


def children_of(machine: Machine) -> dict[str | None, list[str]]:
    """Child body names of every body (None: the roots), in description order."""
    out: dict[str | None, list[str]] = {}
    for b in machine.bodies:
        out.setdefault(b.parent, []).append(b.name)
    return out


def dfs_bodies(machine: Machine) -> list[str]:
    """Body names in MJCF (depth-first) order: the order of MuJoCo's body and joint arrays."""
    return [b.name for b in machine.depth_first]


def root_body(machine: Machine) -> str:
    """Name of the free-floating root body; `ModelError` if the first body is not one."""
    root = machine.bodies[0]
    if root.parent is not None or root.joint.kind != "free":
        raise ModelError(f"the first body '{root.name}' must be the free-floating root")
    return root.name


def body_poses_in_fb(machine: Machine, q_tree) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Pose of every body frame in the floating-base (root body) frame fb.

    Args:
        machine: The machine description.
        q_tree: Tree joint coordinates [rad or m], shape (n_tree,), order
            `Machine.moving_joints`.

    Returns:
        ``{body name: (rotation fb <- body (3, 3), body origin in fb [m] (3,))}``.
    """
    names = machine.moving_joints
    q_tree = np.asarray(q_tree, float)
    if q_tree.shape != (len(names),):
        raise ModelError(f"q_tree must have shape ({len(names)},), got {q_tree.shape}")
    q_of = dict(zip(names, q_tree))
    poses: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for b in machine.bodies:
        if b.parent is None:
            poses[b.name] = (np.eye(3), np.zeros(3))
            continue
        rot_p, pos_p = poses[b.parent]
        rot = rot_p @ b.rotation
        pos = pos_p + rot_p @ b.position
        if b.joint.kind == "revolute":
            rot = rot @ axis_rotation(b.joint.axis, q_of[b.name])
        elif b.joint.kind == "prismatic":
            axis = np.asarray(b.joint.axis, float)
            pos = pos + rot @ (axis / np.linalg.norm(axis)) * q_of[b.name]
        poses[b.name] = (rot, pos)
    return poses


SEAL_FRICTION_SOLREF = (0.004, 1.0)  # [s, -] of the cylinders' seal friction rows


def add_body(parent: ET.Element, machine: Machine, name: str, children) -> None:
    """Append the MJCF ``body`` of ``name`` (joint, inertia, geoms, sites) and its subtree."""
    b = machine.body(name)
    attrs = dict(name=name, pos=fmt(b.position))
    if not np.allclose(b.rotation, np.eye(3)):
        attrs["quat"] = fmt(quat(b.rotation))
    if b.parent is None:
        attrs["childclass"] = "machine"
    el = ET.SubElement(parent, "body", attrs)
    i = b.inertia.inertia
    ET.SubElement(el, "inertial", pos=fmt(b.inertia.com), mass=fmt(b.inertia.mass),
                  fullinertia=fmt((i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2])))
    if b.joint.kind == "free":
        ET.SubElement(el, "freejoint", name=name)
    elif b.joint.kind in JOINT_TYPE:
        j = b.joint
        jattrs = dict(name=name, type=JOINT_TYPE[j.kind], axis=fmt(j.axis))
        if j.range is not None:
            jattrs["range"] = fmt(j.range)
        if j.damping:
            jattrs["damping"] = fmt(j.damping)
        seal = next((c.cylinder.seal_friction for c in machine.chains.values()
                     if c.piston == name), 0.0)
        if seal:
            # Dry friction: MuJoCo's friction rows are soft; a short time constant makes the
            # force reach the seal's rating at a few mm/s instead of a few dm/s.
            jattrs["frictionloss"] = fmt(seal)
            jattrs["solreffriction"] = fmt(SEAL_FRICTION_SOLREF)
        if j.armature:
            jattrs["armature"] = fmt(j.armature)
        ET.SubElement(el, "joint", jattrs)
    n_visual = 0
    for g in b.geoms:
        gattrs = {"class": "collision" if g.collision else "visual", "type": g.kind,
                  "size": fmt(g.size), "rgba": fmt(g.rgba)}
        if g.collision:
            gattrs["name"] = f"{name}_collision"
        else:
            gattrs["name"] = f"{name}_visual{n_visual}"
            n_visual += 1
        if np.any(np.asarray(g.position) != 0):
            gattrs["pos"] = fmt(g.position)
        if not np.allclose(g.rotation, np.eye(3)):
            gattrs["quat"] = fmt(quat(g.rotation))
        ET.SubElement(el, "geom", gattrs)
    for loop in machine.loops:
        for side, body, point in (("a", loop.body_a, loop.point_a),
                                  ("b", loop.body_b, loop.point_b)):
            if body == name:
                ET.SubElement(el, "site", {"name": f"{loop.name}_{side}", "class": "loop_point",
                                           "pos": fmt(point)})
    for chain_name, binding in machine.chains.items():
        barrel = machine.body(binding.barrel)
        if barrel.parent == name:
            ET.SubElement(el, "site", {"name": f"{chain_name}_cylinder_pivot",
                                       "class": "loop_point", "pos": fmt(barrel.position)})
    if name == machine.tcp_body:
        ET.SubElement(el, "site", {"name": "tcp", "class": "loop_point",
                                   "pos": fmt(machine.tcp_position)})
    for child in children.get(name, []):
        add_body(el, machine, child, children)


def chain_loop(machine: Machine, chain_name: str) -> Loop:
    """The loop closing a cylinder chain: piston rod eye on the driven link."""
    binding = machine.chains[chain_name]
    for loop in machine.loops:
        if {loop.body_a, loop.body_b} == {binding.piston, binding.driven_joint}:
            return loop
    raise ModelError(f"no loop closes chain '{chain_name}' (piston '{binding.piston}' to "
                     f"driven link '{binding.driven_joint}')")


def pretty(root: ET.Element) -> str:
    """MJCF text of an element tree, indented by two spaces."""
    ET.indent(root, space="  ")
    return ET.tostring(root, encoding="unicode") + "\n"
