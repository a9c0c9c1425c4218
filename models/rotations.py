"""Rotations and rigid poses: the one module for SO(3)/SE(3) basics used everywhere.

The screw-theory operators of the estimator (`estimators.spatial`: Ad, Ad*, ad, ad*) build
on these. The CasADi backend of the estimator keeps its own symbolic ops where it must.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["axis_rotation", "cross3", "rpy_rotation", "se3", "se3_inverse", "skew"]


def cross3(a, b) -> np.ndarray:
    """``a x b`` of two 3-vectors (numpy's ``cross`` costs ~10 us a call)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                     a[0] * b[1] - a[1] * b[0]])


def skew(v) -> np.ndarray:
    """Skew-symmetric matrix ``[v]`` with ``[v] w = v x w``, shape (3, 3)."""
    x, y, z = v
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def axis_rotation(axis, angle: float) -> np.ndarray:
    """Rotation by a scalar ``angle`` [rad] about ``axis`` (normalised here), Rodrigues, (3, 3)."""
    a = np.asarray(axis, float)
    k = skew(a / np.linalg.norm(a))
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def rpy_rotation(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """``Rz(yaw) Ry(pitch) Rx(roll)`` [rad], shape (3, 3)."""
    return (axis_rotation((0, 0, 1), yaw) @ axis_rotation((0, 1, 0), pitch)
            @ axis_rotation((1, 0, 0), roll))


def se3(rotation, position) -> np.ndarray:
    """Homogeneous 4x4 matrix of the pose (``rotation`` (3, 3), ``position`` (3,) [m])."""
    t = np.eye(4)
    t[:3, :3] = rotation
    t[:3, 3] = position
    return t


def se3_inverse(t: np.ndarray) -> np.ndarray:
    """Inverse of a homogeneous 4x4 pose."""
    r = t[:3, :3]
    out = np.eye(4)
    out[:3, :3] = r.T
    out[:3, 3] = -r.T @ t[:3, 3]
    return out
