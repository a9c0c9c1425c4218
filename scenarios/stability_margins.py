r"""Stability margins beside the minimum normal force: force-angle and ZMP-to-edge distance.

From the ground truth of a log (MuJoCo's wheel contacts and the machine's centre of mass):

* **Force-angle stability measure** (Papadopoulos and Rey, 1996). The wheels in contact,
  taken around the perimeter (FL, FR, RR, RL), span the tip-over axes ``a_i`` (unit, along
  each edge of the support polygon). With ``c`` the centre of mass and ``f_r`` the net
  force on the machine other than the ground's (``f_r = -sum f_contact``: weight and inertia),
  ``l_i`` is the normal from axis ``i`` to ``c`` and ``f_i = (I - a_i a_i^T) f_r``; the
  angle ``theta_i`` between ``f_i`` and ``l_i`` is positive while ``f_i`` points inside the
  polygon. ``beta = min_i theta_i |l_i| |f_r|`` [N m]; it reaches 0 when the machine
  starts to tip about an edge.
* **ZMP margin**: the zero-moment point is the centre of pressure of the contact forces (on
  the ground's mean plane); its distance to the nearest edge of the support polygon, in the
  plane normal to ``f_r`` [m], positive inside.

Both are evaluated per control-rate sample; with fewer than three wheels in contact the
polygon is degenerate and the margins are 0.
"""

from __future__ import annotations

import numpy as np

__all__ = ["PERIMETER", "force_angle_and_zmp"]

PERIMETER = (0, 2, 3, 1)  # FL, FR, RR, RL (package order FL, RL, FR, RR)


def _ring_margins(p: np.ndarray, f: np.ndarray, com: np.ndarray) -> np.ndarray:
    """(beta, smallest theta, ZMP margin) of samples that share one ring, world frame.

    ``p``, ``f``: the ring's contact points and forces in perimeter order, (M, k, 3), k >= 3;
    ``com`` (M, 3). Returns (M, 3); zeros where the ground pushes with no net force.
    """
    f_r = -f.sum(axis=1)
    norm_f = np.linalg.norm(f_r, axis=1)
    ok = norm_f > 0.0
    down = f_r / np.where(ok, norm_f, 1.0)[:, None]
    # Orient each ring counter-clockwise seen against f_r (from "above").
    centre = p.mean(axis=1)
    rel = p - centre[:, None]
    area = np.einsum("mkj,mj->m", np.cross(rel, np.roll(rel, -1, axis=1)), -down)
    p_ccw = np.where((area < 0)[:, None, None], p[:, ::-1], p)
    fz = np.maximum(-np.einsum("mkj,mj->mk", f, down), 0.0)  # pressure along f_r
    total = fz.sum(axis=1)
    cop = np.where((total > 0)[:, None],
                   np.einsum("mk,mkj->mj", fz, p) / np.where(total > 0, total, 1.0)[:, None],
                   centre)
    a = np.roll(p_ccw, -1, axis=1) - p_ccw  # each edge, (M, k, 3)
    a /= np.linalg.norm(a, axis=2, keepdims=True)
    rel = com[:, None] - p_ccw
    lv = rel - a * np.einsum("mkj,mkj->mk", a, rel)[..., None]
    fi = f_r[:, None] - a * np.einsum("mkj,mj->mk", a, f_r)[..., None]
    ln, fn = np.linalg.norm(lv, axis=2), np.linalg.norm(fi, axis=2)
    edge = (ln > 0.0) & (fn > 0.0)
    # Inward normal of each edge in the ground plane (counter-clockwise ring); the signed
    # angle from -l (centre of mass towards the axis) to f_i, positive towards the inside:
    # f_i through the edge is theta = 0.
    inward = np.cross(-down[:, None], a)
    u = -lv / np.where(edge, ln, 1.0)[..., None]
    w = inward - u * np.einsum("mkj,mkj->mk", inward, u)[..., None]
    w /= np.linalg.norm(w, axis=2, keepdims=True)
    theta = np.arctan2(np.einsum("mkj,mkj->mk", fi, w), np.einsum("mkj,mkj->mk", fi, u))
    inf = np.full_like(theta, np.inf)
    out = np.stack([np.where(edge, theta * ln * norm_f[:, None], inf).min(axis=1),
                    np.where(edge, theta, inf).min(axis=1),
                    np.where(edge, np.einsum("mkj,mkj->mk", cop[:, None] - p_ccw, inward),
                             inf).min(axis=1)], axis=1)
    out[~ok] = 0.0
    return out


def force_angle_and_zmp(base_position: np.ndarray, base_rotation: np.ndarray,
                        point_in_fb: np.ndarray, force_in_fb: np.ndarray,
                        in_contact: np.ndarray, com_world: np.ndarray) -> dict:
    """Per-sample margins of a log (module docstring).

    Args:
        base_position: fb origin in the world [m], (N, 3).
        base_rotation: Rotation world <- fb, (N, 3, 3).
        point_in_fb: Ground-truth contact points [m], (N, 4, 3).
        force_in_fb: Ground-truth contact forces [N], (N, 4, 3).
        in_contact: Contact flags, (N, 4).
        com_world: Centre of mass of the machine in the world [m], (N, 3).

    Returns:
        ``beta_Nm``, ``theta_rad``, ``zmp_margin_m``: arrays of shape (N,).
    """
    n = base_position.shape[0]
    out = np.zeros((n, 3))
    pts = np.einsum("nij,nkj->nki", base_rotation, point_in_fb) + base_position[:, None]
    frc = np.einsum("nij,nkj->nki", base_rotation, force_in_fb)
    contact = np.asarray(in_contact, bool)
    com = np.asarray(com_world, float)
    # Samples grouped by which wheels touch: one ring each (fewer than three: zeros).
    for pattern in np.unique(contact, axis=0):
        ring = [k for k in PERIMETER if pattern[k]]
        if len(ring) < 3:
            continue
        rows = np.flatnonzero((contact == pattern).all(axis=1))
        out[rows] = _ring_margins(pts[rows][:, ring], frc[rows][:, ring], com[rows])
    return {"beta_Nm": out[:, 0], "theta_rad": out[:, 1], "zmp_margin_m": out[:, 2]}
