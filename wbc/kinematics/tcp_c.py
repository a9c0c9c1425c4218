"""The TCP's supporting tree coordinates in C: `TcpKinematics.position`'s Python loop in one call.

`TcpKinematics.position` writes Pinocchio's configuration of the joints that support the TCP
(`TcpKinematics._position_plan`): the crane's directly driven coordinates as they are, the
slew, lift and tilt joints from their chains' strokes (`models.chain.Chain.angles`, eqs.
(2)-(5): ``theta = psi + sigma q``, ``q = -acos(clip(c, -1, 1))``, ``c`` the law of cosines),
after checking that every entry of ``q`` is finite and every chain's stroke in its range. In
Python that is ~3 us a call of float arithmetic and method calls; ``tcp_tree`` does the same
IEEE operations in the same order (no fused multiply-adds: `models.cbuild`; the C library's
``acos``, the one Python's ``math.acos`` calls; Python's ``max``/``min`` ties: the first
argument), so the configuration, and the TCP, are the Python path's bits. It returns nonzero
when a check fails: the Python path then runs and raises its typed error.
Tested against the Python path on closed-loop ticks and random coordinates, bit for bit
(`tests/test_wbc_kinematics.py`).
"""

from __future__ import annotations

import ctypes

import numpy as np

from models.cbuild import bind, load_shared
from models.coordinates import N_INDEPENDENT

__all__ = ["TCP_C", "compiled_tcp_tree"]

# One row per chain (`chain_rows`): independent index, Pinocchio's q index of the driven
# joint (-1: not a supporting joint, checked only), la, lb, lx0, psi, sigma, stroke lo, hi.
_CHAIN_ROW = 9

TCP_C = f"#define NI {N_INDEPENDENT}\n#define ROW {_CHAIN_ROW}\n" + r"""
#include <math.h>
/* 0, the supporting entries of qp written; 1: a non-finite q; 2: a stroke out of range. */
int tcp_tree(const double* q, const long* direct, long n_direct, const double* chains,
             long n_chains, double* qp) {
  long i;
  for (i = 0; i < NI; ++i)
    if (!isfinite(q[i])) return 1;
  for (i = 0; i < n_direct; ++i) qp[direct[2 * i + 1]] = q[direct[2 * i]];
  for (i = 0; i < n_chains; ++i) {
    const double* r = chains + ROW * i;
    const double x = q[(long)r[0]], la = r[2], lb = r[3];
    double lx, c, m;
    if (!(r[7] - 1e-12 <= x && x <= r[8] + 1e-12)) return 2;  /* Chain.check_stroke */
    if (r[1] < 0) continue;
    lx = r[4] + x;
    c = ((la * la + lb * lb) - lx * lx) / ((2 * la) * lb);
    m = (-1.0 > c) ? -1.0 : c;  /* max(c, -1.0) */
    m = (1.0 < m) ? 1.0 : m;    /* min(., 1.0) */
    qp[(long)r[1]] = r[5] + r[6] * -acos(m);
  }
  return 0;
}
"""


def chain_rows(chains) -> np.ndarray:
    """`TCP_C`'s chain table of `TcpKinematics._chains` ((index, chain, q index or None))."""
    rows = []
    for i, chain, j in chains:
        k = chain._consts
        lo, hi = chain.stroke_range
        rows.append((i, -1 if j is None else j, k["la"], k["lb"], k["lx0"], k["psi"],
                     chain.sigma, lo, hi))
    return np.array(rows, float).reshape(-1, _CHAIN_ROW)


def compiled_tcp_tree(direct, chains, q_in: np.ndarray, qp: np.ndarray):
    """``tcp_tree`` bound to the kept input ``q_in`` (13,) and configuration ``qp``.

    Returns a callable of no arguments giving the C's code, and the arrays it reads (for the
    caller to keep), or None without a working compiler.
    """
    lib = load_shared(TCP_C, "tcp_tree", {"tcp_tree": (
        [ctypes.c_void_p] * 2 + [ctypes.c_long, ctypes.c_void_p, ctypes.c_long,
                                 ctypes.c_void_p], ctypes.c_int)}, "the Python TCP tree")
    if lib is None:
        return None
    pairs = np.array(direct, np.int64).reshape(-1, 2)
    rows = chain_rows(chains)
    return bind(lib.tcp_tree, q_in, pairs, len(pairs), rows, len(rows), qp), (pairs, rows)
