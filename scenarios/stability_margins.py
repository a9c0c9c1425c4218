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


def _margins(points: np.ndarray, forces: np.ndarray, in_contact: np.ndarray,
             com: np.ndarray) -> tuple[float, float, float]:
    """(beta [N m], smallest theta [rad], ZMP margin [m]) of one sample (world frame)."""
    ring = [k for k in PERIMETER if in_contact[k]]
    if len(ring) < 3:
        return 0.0, 0.0, 0.0
    f_r = -forces[ring].sum(axis=0)
    norm_f = float(np.linalg.norm(f_r))
    if norm_f == 0.0:
        return 0.0, 0.0, 0.0
    down = f_r / norm_f
    p = points[ring]
    # Orient the ring counter-clockwise seen against f_r (from "above").
    centre = p.mean(axis=0)
    area = sum(np.cross(p[i] - centre, p[(i + 1) % len(p)] - centre) @ -down
               for i in range(len(p)))
    if area < 0:
        p = p[::-1]
    fz = np.maximum(-(forces[ring] @ down), 0.0)  # pressure along f_r
    cop = (fz @ points[ring]) / fz.sum() if fz.sum() > 0 else centre
    beta, theta_min, zmp = np.inf, np.inf, np.inf
    for i in range(len(p)):
        a = p[(i + 1) % len(p)] - p[i]
        a /= np.linalg.norm(a)
        proj = np.eye(3) - np.outer(a, a)
        rel = com - p[i]
        lv = proj @ rel
        fi = proj @ f_r
        ln, fn = np.linalg.norm(lv), np.linalg.norm(fi)
        if ln == 0.0 or fn == 0.0:
            continue
        # Inward normal of the edge in the ground plane (counter-clockwise ring).
        inward = np.cross(-down, a)
        # Signed angle from -l (centre of mass towards the axis) to f_i, positive towards
        # the inside of the polygon: f_i through the edge is theta = 0.
        u = -lv / ln
        w = inward - (inward @ u) * u
        w /= np.linalg.norm(w)
        theta = float(np.arctan2(fi @ w, fi @ u))
        beta = min(beta, theta * ln * norm_f)
        theta_min = min(theta_min, theta)
        zmp = min(zmp, float((cop - p[i]) @ inward))
    return float(beta), float(theta_min), float(zmp)


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
    for i in range(n):
        out[i] = _margins(pts[i], frc[i], np.asarray(in_contact[i], bool), com_world[i])
    return {"beta_Nm": out[:, 0], "theta_rad": out[:, 1], "zmp_margin_m": out[:, 2]}
