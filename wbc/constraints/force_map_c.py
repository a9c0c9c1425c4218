"""The MPC's predicted-force map ``(A, b)`` in C: one call per tick instead of ~40 numpy ops.

`HorizonNormalForceConstraint` predicts the four normal forces at every node of the horizon
as ``A x + b`` (its docstring has the model). In numpy that is a few dozen operations on
small arrays, each one mostly call overhead (~0.15 ms a tick, cache-cold in the loop, for a
few thousand multiplications). `FORCE_MAP_C` is the same arithmetic as loops over what is
not structurally zero: the condensed prediction of every axis is ``kron(Lq, I)`` on the
inputs, so node k's row of wheel i reads ``dq[k, i, a] Lq[k-1, j] + dqd[k, i, a] Lv[k-1,
j]`` in the column of step j's input to axis a. Compiled once with the system compiler
(`models.cbuild`) and called through ctypes with one block of pointers; the numpy version
stays as the fallback without a compiler and as the test's oracle
(`tests/test_force_map_c.py`: the same ``A`` to the bit where the numpy sums hold one
nonzero term, ``b`` to round-off). The linearizations come in as their kernel rows: read
from `ForceLinearization` objects (`CompiledForceMap.evaluate`), or handed over as rows
(`CompiledForceMap.evaluate_rows`, the MPC's tick: `tests/test_horizon_rows.py`).
"""

from __future__ import annotations

import ctypes
from struct import Struct

import numpy as np

from models.cbuild import address, load_shared
from models.coordinates import N_INDEPENDENT, SUSPENSION
from wbc.axes import N_AXES
from wbc.force_models.feedback import DIAGONAL

__all__ = ["FORCE_MAP_C", "CompiledForceMap", "compiled_force_map", "row_offsets"]

# Integer header `iv` (then `which` and `j` of every node), double header `dv`, pointers `p`.
_I_NAMES = ("n_eval", "n_steps", "n", "row_len", "off_g", "off_dq", "off_dqd", "off_g0",
            "scale", "susp_lo", "susp_hi", "zero_susp", "warp", "direction", "bias",
            "drift", "terminal")
_D_NAMES = ("speed_scale", "brake_time", "s_prev")
_P_NAMES = ("rows", "lq", "lv", "since", "decay", "omega", "free_q", "free_v", "qn", "vn",
            "q0", "warp", "direction", "bias", "drift", "diagonal", "twist", "qd", "thresholds")
# `force_rows`' double header: `_D_NAMES`, then the drive's factor and the rows' scale.
_T_NAMES = (*_D_NAMES, "drive_factor", "force_scale")
NW, NA, NQ = 4, N_AXES, N_INDEPENDENT  # wheels, axes, coordinates (as in FORCE_MAP_C)
NG = 6 + NQ  # accelerations: base twist, coordinates
IV = {name: k for k, name in enumerate(_I_NAMES)}  # places in the headers
DV = {name: k for k, name in enumerate(_D_NAMES)}
_ROW_HEADER = slice(IV["row_len"], IV["off_g0"] + 1)  # row length, then the offsets
_TERM_FLAGS = slice(IV["zero_susp"], IV["drift"] + 1)  # which terms a tick has
if _I_NAMES[_ROW_HEADER] != ("row_len", "off_g", "off_dq", "off_dqd", "off_g0") \
        or _I_NAMES[_TERM_FLAGS] != ("zero_susp", "warp", "direction", "bias", "drift") \
        or _D_NAMES != ("speed_scale", "brake_time", "s_prev"):
    raise ImportError("the headers' order differs from what evaluate writes")

FORCE_MAP_C = r"""
#include <string.h>
enum { NW = 4, NA = 9, NB = 6, NG = 19, NQ = 13, N_HEADER = 17 };
/* Mirrors `HorizonNormalForceConstraint._forces_map` (the numpy version), step by step.
   A: (n_eval, 4, n) row-major, b: (n_eval, 4). */
int force_map(const double* const* p, const long long* iv, const double* dv,
              double* restrict A, double* restrict b) {
  const long long n_eval = iv[0], N = iv[1], n = iv[2], row_len = iv[3];
  const long long off_g = iv[4], off_dq = iv[5], off_dqd = iv[6], off_g0 = iv[7];
  const long long scale = iv[8], s_lo = iv[9], s_hi = iv[10], zero_susp = iv[11];
  const int has_warp = (int)iv[12], has_dir = (int)iv[13], has_bias = (int)iv[14];
  const int has_drift = (int)iv[15], terminal = (int)iv[16];
  const long long* which = iv + N_HEADER;
  const long long* jn = which + n_eval;
  const double speed_scale = dv[0], Tb = dv[1], s_prev = dv[2];
  const double *rows = p[0], *Lq = p[1], *Lv = p[2], *since = p[3], *decay = p[4];
  const double *omega = p[5], *fq = p[6], *fv = p[7], *qn = p[8], *vn = p[9], *q0 = p[10];
  const double *warp = p[11], *dir = p[12], *bias = p[13], *drift = p[14], *diag = p[15];
  double G[NW][NG], dq[NW][NQ], dqd[NW][NQ];
  long long k, i, a, jj, c, n_u = n_eval < N ? n_eval : N;
  if (n_eval < 1 || N < 1 || n < N * NA || n_eval > N + 1) return -1;
  memset(A, 0, sizeof(double) * (size_t)(n_eval * NW * n));
  for (k = 0; k < n_eval; ++k) {
    const double* row = rows + which[k] * row_len;
    double* Ak = A + k * NW * n;
    double* bk = b + k * NW;
    memcpy(G, row + off_g, sizeof G);
    memcpy(dq, row + off_dq, sizeof dq);
    memcpy(dqd, row + off_dqd, sizeof dqd);
    if (zero_susp) {  /* the suspension acts through the warp model only */
      for (i = 0; i < NW; ++i)
        for (a = s_lo; a < s_hi; ++a) { G[i][NB + a] = 0.0; dq[i][a] = 0.0; dqd[i][a] = 0.0; }
    }
    for (i = 0; i < NW; ++i) {  /* b = g0 + (dq_wheels . omega) * since_j */
      double s = 0.0;
      for (c = 0; c < NQ - NA; ++c) s += dq[i][NA + c] * omega[c];
      bk[i] = row[off_g0 + i] + s * since[k];
    }
    if (k >= 1) {  /* the configuration along the condensed prediction */
      const double* lq = Lq + (k - 1) * N;
      const double* lv = Lv + (k - 1) * N;
      const double* dqk = fq + (k - 1) * NA;
      const double* dvk = fv + (k - 1) * NA;
      const double* qj = qn + jn[k] * NA;
      const double* vj = vn + jn[k] * NA;
      for (i = 0; i < NW; ++i) {
        double* Ai = Ak + i * n;
        double s = 0.0, t = 0.0;
        for (jj = 0; jj < N; ++jj) {
          if (lq[jj] == 0.0 && lv[jj] == 0.0) continue;
          for (a = 0; a < NA; ++a)
            Ai[jj * NA + a] = dq[i][a] * lq[jj] + dqd[i][a] * lv[jj];
        }
        for (a = 0; a < NA; ++a) s += dq[i][a] * (dqk[a] - qj[a]);
        for (a = 0; a < NA; ++a) t += dqd[i][a] * (dvk[a] - vj[a]);
        bk[i] += s + t;
      }
    }
    if (k < n_u) {  /* step k's own input: the accelerations' direct effect */
      for (i = 0; i < NW; ++i)
        for (a = 0; a < NA; ++a) Ak[i * n + k * NA + a] = G[i][NB + a];
    }
    if (terminal && k == N) {  /* brake to rest after the horizon: a = -qd_N / T_b */
      const double* lv = Lv + (N - 1) * N;
      const double* vN = fv + (N - 1) * NA;
      for (i = 0; i < NW; ++i) {
        double s = 0.0;
        for (jj = 0; jj < N; ++jj) {
          if (lv[jj] == 0.0) continue;
          for (a = 0; a < NA; ++a) Ak[i * n + jj * NA + a] -= G[i][NB + a] * lv[jj] / Tb;
        }
        for (a = 0; a < NA; ++a) s += G[i][NB + a] * vN[a];
        bk[i] -= s / Tb;
      }
    }
    if (has_warp && k >= 1) {  /* the suspension twists the chassis */
      const double* lq = Lq + (k - 1) * N;
      const double* qk = fq + (k - 1) * NA;
      for (i = 0; i < NW; ++i) {
        double s = 0.0;
        for (jj = 0; jj < N; ++jj) {
          if (lq[jj] == 0.0) continue;
          for (a = 0; a < NA; ++a) Ak[i * n + jj * NA + a] += warp[i * NA + a] * lq[jj];
        }
        for (a = 0; a < NA; ++a) s += (qk[a] - q0[a]) * warp[i * NA + a];
        bk[i] += s;
      }
    }
    if (has_dir && scale >= 0) {  /* the wheel-speed scale's drive acceleration */
      for (i = 0; i < NW; ++i) {
        double s = 0.0;
        for (c = 0; c < NG; ++c) s += G[i][c] * dir[c];
        s *= decay[k];
        Ak[i * n + scale] += s;
        bk[i] -= s * speed_scale;
      }
    }
    if (has_bias)
      for (i = 0; i < NW; ++i) bk[i] += bias[i];
    if (has_drift) {  /* the terrain keeps twisting */
      for (i = 0; i < NW; ++i) {
        double d = drift[k] * diag[i];
        bk[i] += d;
        if (scale >= 0) {
          Ak[i * n + scale] += d / s_prev;
          bk[i] -= d * speed_scale / s_prev;
        }
      }
    }
  }
  return 0;
}

/* The constraint's rows on `force_map`'s A, b (written to out: A, b, then G, h): row r of
   G x <= h is A's row src[r] over -force_scale, with -1 in its slack column (if >= 0),
   h[r] = (b[src[r]] - thresholds[wheel[r]]) / force_scale; with iv's direction flag the
   drive's direction first, `wbc.drive_model.speed_scale_direction` (the base's horizontal
   twist and the wheel speeds times dv[3]). plan: m, capacity, then src, wheel, slack
   (capacity each). */
int force_rows(const double* const* p, const long long* iv, const double* dv,
               const long long* plan, double* out) {
  const long long n_eval = iv[0], n = iv[2], m_all = NW * n_eval;
  const long long m = plan[0], cap = plan[1];
  const long long *src = plan + 2, *wheel = src + cap, *slack = wheel + cap;
  const double k = dv[3], fs = dv[4], nfs = -fs;
  const double *twist = p[16], *qd = p[17], *thr = p[18];
  double *A = out, *b = out + m_all * n;
  double* restrict G = b + m_all;
  double* restrict h = G + m * n;
  long long r, c;
  if (m < 0 || m > cap) return -1;
  for (r = 0; r < m; ++r)
    if (src[r] < 0 || src[r] >= m_all || wheel[r] < 0 || wheel[r] >= NW || slack[r] >= n)
      return -1;
  if (iv[13]) {
    double* d = (double*)p[12];
    memset(d, 0, sizeof(double) * NG);
    d[0] = k * twist[0];
    d[1] = k * twist[1];
    for (c = NA; c < NQ; ++c) d[NB + c] = k * qd[c];
  }
  if (force_map(p, iv, dv, A, b)) return -1;
  for (r = 0; r < m; ++r) {
    const double* restrict a = A + src[r] * n;
    double* g = G + r * n;
    for (c = 0; c < n; ++c) g[c] = a[c] / nfs;
    if (slack[r] >= 0) g[slack[r]] = -1.0;
    h[r] = (b[src[r]] - thr[wheel[r]]) / fs;
  }
  return 0;
}
"""
# The C source's sizes are this module's.
if "NA = %d, NB = 6, NG = %d, NQ = %d, N_HEADER = %d" % (NA, NG, NQ, len(_I_NAMES)) \
        not in FORCE_MAP_C:
    raise ImportError("FORCE_MAP_C's sizes differ from the coordinates'")


class CompiledForceMap:
    """`FORCE_MAP_C` with the buffers of one constraint (not shared between threads).

    `evaluate` copies a tick's inputs into buffers that a block of pointers points at (kept
    while the horizon's structure stays the same) and writes fresh ``A``, ``b`` (views of one
    new block).
    """

    def __init__(self, fun, rows_fun=None):
        self._fun = fun
        self._rows_fun = rows_fun  # `force_rows` (`evaluate_tick`)
        self._key: tuple | None = None
        self._header: tuple | None = None

    def prepare(self, struct, n_steps: int, n: int, scale, rows_shape: tuple) -> None:
        """Make the buffers of a structure and rows' shape now, not at the first call."""
        self._buffers(struct, n_steps, n, scale, rows_shape)

    def _buffers(self, struct, n_steps: int, n: int, scale, rows_shape: tuple) -> None:
        """The buffers of a structure (`HorizonNormalForceConstraint._structure`)."""
        kept = self._key
        if (kept is not None and kept[0] is struct and kept[1] == n_steps and kept[2] == n
                and kept[3] == scale and kept[4] == rows_shape):
            return  # the common case, without the key's tuple
        key = (struct, n_steps, n, scale, rows_shape)
        if kept is not None and all(map(_same, kept, key)):
            return
        self._header = None  # the new ``iv`` has no row header and flags yet (`_run`)
        N, n_eval = n_steps, struct.n_eval
        head = len(_I_NAMES)
        iv = self.iv = np.zeros(head + 2 * n_eval, np.int64)
        iv[head:head + n_eval] = struct.which
        iv[head + n_eval:] = struct.j
        iv[IV["n_eval"]], iv[IV["n_steps"]], iv[IV["n"]] = n_eval, N, n
        iv[IV["scale"]] = -1 if scale is None else scale
        iv[IV["terminal"]] = n_eval > N
        iv[IV["susp_lo"]], iv[IV["susp_hi"]] = SUSPENSION.start, SUSPENSION.stop
        # What a tick brings, in one block in `evaluate_tick`'s order: one copy of its bytes.
        shapes = {"head": (len(_T_NAMES),), "rows": rows_shape, "qd": (NQ,), "twist": (6,),
                  "free_q": (N, NA), "free_v": (N, NA), "q0": (NA,), "warp": (NW, NA),
                  "bias": (NW,), "drift": (n_eval,), "thresholds": (NW,)}
        sizes = [int(np.prod(shape)) for shape in shapes.values()]
        block = self._block = np.zeros(sum(sizes))
        self._block_raw = memoryview(block).cast("B")
        ends = np.cumsum(sizes)
        a = {name: block[end - size:end].reshape(shape)
             for (name, shape), size, end in zip(shapes.items(), sizes, ends)}
        self.dv = a.pop("head")  # `_D_NAMES`, then the rest of `_T_NAMES`
        self._iv_at, self._dv_at = iv.ctypes.data, self.dv.ctypes.data
        a.update({
            "lq": np.ascontiguousarray(struct.lq, float),
            "lv": np.ascontiguousarray(struct.lv, float),
            "since": np.ascontiguousarray(struct.since_j[:, 0], float),
            "decay": np.ascontiguousarray(struct.decay[:, 0], float), "omega": a["qd"][NA:NQ],
            "qn": np.zeros((N + 1, NA)), "vn": np.zeros((N + 1, NA)),
            "direction": np.zeros(NG), "diagonal": np.array(DIAGONAL, float),
            "no_warp": np.zeros((NW, NA)), "no_bias": np.zeros(NW), "no_drift": np.zeros(n_eval)})
        self.arrays = a
        self.pointers = (ctypes.c_void_p * len(_P_NAMES))(
            *(a[name].ctypes.data for name in _P_NAMES))
        self._key = key

    def evaluate(self, struct, n_steps: int, n: int, scale, lins, ctx, qn, vn, *,
                 zero_suspension: bool, warp, direction, bias, drift, s_prev: float,
                 brake_time: float | None) -> tuple[np.ndarray, np.ndarray]:
        """``(A, b)`` as `HorizonNormalForceConstraint._forces_map` computes them.

        ``lins``: the linearizations (`ForceLinearization`); ``warp``, ``direction``,
        ``bias``, ``drift``: None where the numpy version skips the term.
        """
        views = lins[0].__dict__.get("_views")
        slices = getattr(views, "slices", None)
        rowed = slices is not None and all(o.__dict__.get("_views") is views for o in lins)
        width = lins[0].__dict__["_row"].size if rowed else _OWN_ROW
        self._buffers(struct, n_steps, n, scale, (len(lins), width))
        rows = self.arrays["rows"]
        if rowed:
            for k, lin in enumerate(lins):
                rows[k] = lin.__dict__["_row"]
            offsets = row_offsets(views)
        else:
            for k, lin in enumerate(lins):
                for name, (lo, hi) in _OWN_FIELDS.items():
                    rows[k, lo:hi] = np.ravel(getattr(lin, name))
            offsets = tuple(lo for lo, _ in _OWN_FIELDS.values())
        return self._run(struct, n, width, offsets, ctx, qn, vn, zero_suspension, warp,
                         direction, bias, drift, s_prev, brake_time)

    def evaluate_rows(self, struct, n_steps: int, n: int, scale, first: np.ndarray,
                      later: np.ndarray, offsets: tuple, ctx, qn, vn, *,
                      zero_suspension: bool, warp, direction, bias, drift, s_prev: float,
                      brake_time: float | None) -> tuple[np.ndarray, np.ndarray]:
        """`evaluate` of linearizations given as kernel rows: the same ``(A, b)``, bit for bit.

        ``first``: node 0's row (width,), ``later``: the later nodes' rows (m, width), both
        laid out as ``offsets`` (`row_offsets`) say; copied in, not kept.
        """
        width = first.size
        self._buffers(struct, n_steps, n, scale, (1 + len(later), width))
        rows = self.arrays["rows"]
        rows[0] = first
        rows[1:] = later
        return self._run(struct, n, width, offsets, ctx, qn, vn, zero_suspension, warp,
                         direction, bias, drift, s_prev, brake_time)

    def nominal(self, struct, n_steps: int, n: int, scale, rows_shape: tuple
                ) -> tuple[np.ndarray, np.ndarray] | None:
        """The buffers ``(qn, vn)`` (N + 1, 9) of `evaluate_tick`, for the caller to fill.

        None without `force_rows` or where the buffers kept are not those of this structure
        and rows' shape (`prepare`): then `evaluate_rows`.
        """
        kept = self._key
        if (self._rows_fun is None or kept is None or kept[0] is not struct
                or kept[1] != n_steps or kept[2] != n or kept[3] != scale
                or kept[4] != rows_shape):
            return None
        return self.arrays["qn"], self.arrays["vn"]

    def evaluate_tick(self, n_eval: int, n: int, offsets: tuple, ctx, first: np.ndarray,
                      later: np.ndarray, plan: tuple, thresholds: np.ndarray, *,
                      zero_suspension: bool, warp, direction: float | None, bias, drift,
                      s_prev: float, brake_time: float | None, force_scale: float
                      ) -> tuple | None:
        """``(A, b, G, h)``: `evaluate_rows`' ``(A, b)`` and the constraint's rows, one call.

        After `nominal` (whose buffers hold this tick's nominal states). ``direction``: the
        factor of `wbc.drive_model.speed_scale_direction` (``1 / (tau max(s, s_min))``;
        None: no such term); ``plan``: ``(int64 array, its address)`` of ``force_rows``'
        plan (m, capacity, then the rows of A, their wheels and slack columns);
        ``thresholds``: each wheel's [N], (4,). G and h are those of
        `ForceRowsConstraint.compute` on ``(A, b)``, bit for bit
        (`tests/test_force_tick_c.py`). All four are views of one new block.

        Returns:
            None (nothing evaluated) where the tick's arrays do not fill the block (a row of
            another width, an array of another shape or type): then `evaluate_rows`.
        """
        a = self.arrays
        st = ctx.state
        if first.size != a["rows"].shape[1]:
            return None
        head = _HEAD.pack(ctx.speed_scale, 1.0 if brake_time is None else brake_time, s_prev,
                          0.0 if direction is None else direction, force_scale)
        try:
            data = b"".join((
                head, first, later, st.qd, st.base_twist, ctx.free_positions,
                ctx.free_velocities, ctx.q, a["no_warp"] if warp is None else warp,
                a["no_bias"] if bias is None else bias,
                a["no_drift"] if drift is None else drift[:n_eval], thresholds))
        except (TypeError, ValueError, BufferError):
            return None
        raw = self._block_raw
        if len(data) != len(raw):
            return None
        raw[:] = data
        iv = self.iv
        header = (first.size, *offsets, zero_suspension, warp is not None,
                  direction is not None, bias is not None, drift is not None)
        if header != self._header:
            iv[_ROW_HEADER] = header[:5]
            iv[_TERM_FLAGS] = header[5:]
            self._header = header
        M = NW * n_eval
        m = int(plan[0][0])
        out = np.empty(M * (n + 1) + m * (n + 1))
        at = address(out)
        if self._rows_fun(self.pointers, self._iv_at, self._dv_at, plan[1], at) != 0:
            raise ValueError(f"force rows: inconsistent sizes {iv[:4].tolist()}, plan "
                             f"{plan[0][:2].tolist()}")
        G_at = M * (n + 1)
        return (out[:M * n].reshape(M, n), out[M * n:G_at],
                out[G_at:G_at + m * n].reshape(m, n), out[G_at + m * n:])

    def _run(self, struct, n: int, width: int, offsets: tuple, ctx, qn, vn,
             zero_suspension: bool, warp, direction, bias, drift, s_prev: float,
             brake_time: float | None) -> tuple[np.ndarray, np.ndarray]:
        """The C call on the rows in the buffer (`_buffers`) and this tick's other inputs."""
        a, iv, dv = self.arrays, self.iv, self.dv
        header = (width, *offsets, zero_suspension, warp is not None, direction is not None,
                  bias is not None, drift is not None)
        if header != self._header:  # written when it changes (a wheel lifts, a term comes)
            iv[_ROW_HEADER] = header[:5]
            iv[_TERM_FLAGS] = header[5:]
            self._header = header
        a["omega"][:] = ctx.state.qd[NA:NQ]
        a["free_q"][:] = ctx.free_positions
        a["free_v"][:] = ctx.free_velocities
        a["qn"][:] = qn
        a["vn"][:] = vn
        a["q0"][:] = ctx.q
        if warp is not None:
            a["warp"][:] = warp
        if direction is not None:
            a["direction"][:] = direction
        if bias is not None:
            a["bias"][:] = bias
        if drift is not None:
            a["drift"][:] = drift[:struct.n_eval]
        dv[0] = ctx.speed_scale
        dv[1] = 1.0 if brake_time is None else brake_time
        dv[2] = s_prev
        # A, then b, in one fresh block: one address to take (`models.cbuild.address`)
        m = NW * struct.n_eval
        out = np.empty(m * (n + 1))
        at = address(out)
        if self._fun(self.pointers, self._iv_at, self._dv_at, at, at + 8 * m * n) != 0:
            raise ValueError(f"force map: inconsistent sizes {iv[:4].tolist()}")
        return out[:m * n].reshape(m, n), out[m * n:]


_HEAD = Struct("=%dd" % len(_T_NAMES))


def row_offsets(views) -> tuple[int, int, int, int]:
    """Where ``G``, ``d_q``, ``d_qd``, ``g0`` start in a row of ``views`` (`RowViews`)."""
    slices = views.slices
    return (slices["G"][0].start, slices["d_q"][0].start, slices["d_qd"][0].start,
            slices["g0"][0].start)


def _same(x, y) -> bool:
    return x is y or (type(x) is type(y) and not hasattr(x, "__dict__") and x == y)


# A linearization without a kernel row (a test double's): its fields in a row of our own.
_OWN_FIELDS = {"G": (0, NW * NG), "d_q": (NW * NG, NW * (NG + NQ)),
               "d_qd": (NW * (NG + NQ), NW * (NG + 2 * NQ)),
               "g0": (NW * (NG + 2 * NQ), NW * (NG + 2 * NQ + 1))}
_OWN_ROW = NW * (NG + 2 * NQ + 1)


def compiled_force_map() -> CompiledForceMap | None:
    """A new `CompiledForceMap` (its own buffers), or None without a working compiler.

    The library is compiled (or found in the cache) and loaded once per process.
    """
    lib = load_shared(FORCE_MAP_C, "force_map",
                      {"force_map": ([ctypes.c_void_p] * 5, ctypes.c_int),
                       "force_rows": ([ctypes.c_void_p] * 5, ctypes.c_int)}, "numpy", "-O3")
    return None if lib is None else CompiledForceMap(lib.force_map, lib.force_rows)
