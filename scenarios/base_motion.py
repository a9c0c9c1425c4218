"""Base pose and body twist from MuJoCo's free-joint coordinates."""

from __future__ import annotations

import mujoco
import numpy as np

__all__ = ["base_motion_from_free_joint", "body_motion"]


def base_motion_from_free_joint(qpos7, qvel6, qacc6
                                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Base pose, body twist and its derivative from MuJoCo free-joint coordinates.

    MuJoCo's free joint has ``qvel = [v_world; w_fb]`` (linear velocity of the fb origin in
    world axes, angular velocity in fb axes) and ``qacc`` their time derivatives. With
    ``R`` = rotation world <- fb, the body twist is ``[v_fb; w_fb] = [R^T v_world; w_fb]`` and
    its time derivative (Pinocchio's free-flyer ``a``) is
    ``[R^T a_world - w_fb x v_fb; w_dot_fb]``, since ``d(R^T)/dt = -[w_fb]x R^T``.

    Args:
        qpos7: Position [m] and unit quaternion (w, x, y, z), shape (7,).
        qvel6: Free-joint velocity, shape (6,).
        qacc6: Free-joint acceleration, shape (6,).

    Returns:
        (position [m] (3,), rotation world <- fb (3, 3), twist [m/s, rad/s] (6,),
        twist derivative [m/s^2, rad/s^2] (6,)).
    """
    qpos7, qvel6, qacc6 = (np.asarray(a, float) for a in (qpos7, qvel6, qacc6))
    rotation = np.zeros(9)
    mujoco.mju_quat2Mat(rotation, qpos7[3:7] / np.linalg.norm(qpos7[3:7]))
    rotation = rotation.reshape(3, 3)
    twist, accel = body_motion(rotation, qvel6, qacc6)
    return qpos7[:3].copy(), rotation, twist, accel


def body_motion(rotation: np.ndarray, qvel6: np.ndarray,
                qacc6: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Twist ``[R^T v; w]`` and its derivative ``[R^T a - w x v_fb; w_dot]``.

    See `base_motion_from_free_joint`.

    Args:
        rotation: Rotation world <- fb, shape (3, 3).
        qvel6: Free-joint velocity [m/s, rad/s], shape (6,).
        qacc6: Free-joint acceleration [m/s^2, rad/s^2], shape (6,).

    Returns:
        (twist [m/s, rad/s] (6,), twist derivative [m/s^2, rad/s^2] (6,)), in fb.
    """
    v = rotation.T @ qvel6[:3]
    w = qvel6[3:6]
    w_cross_v = (w[1] * v[2] - w[2] * v[1], w[2] * v[0] - w[0] * v[2], w[0] * v[1] - w[1] * v[0])
    twist = np.empty(6)
    twist[:3], twist[3:] = v, w
    accel = np.empty(6)
    accel[:3] = rotation.T @ qacc6[:3]
    accel[:3] -= w_cross_v
    accel[3:] = qacc6[3:6]
    return twist, accel
