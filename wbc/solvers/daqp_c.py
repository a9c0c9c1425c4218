"""DAQP's least-distance problem solved through its C API on a workspace kept from solve to solve.

`wbc.solvers.DaqpBackend` hands DAQP the least-distance form ``min |u|^2 / 2`` subject to
``lower <= M u <= upper`` (an identity Hessian, no linear term, no simple bounds: the bounds
are the first rows of ``M``). ``daqp.solve`` (the 0.11.0 Cython wrapper) sets DAQP up from
scratch on every call: it allocates a workspace, copies ``M`` into it and normalises every
row (``daqp_update_M``, ``daqp_normalize_M``: the sum of squares of each row in order, one
add after the other's rounding), checks the identity for being diagonal, then runs the
active-set iterations and frees it all: ~75 us of set-up around ~5 us of iterations for the
MPC's ~400 x 117 rows warm started (one iteration, typically).

`LeastDistanceWorkspace` keeps DAQP's workspace while the number of variables stays the same
and the rows fit its arrays (room for a quarter more rows than the set-up had; more rows are
set up afresh), and for every solve leaves in it what a fresh set-up would, with the same
bits (`tests/test_daqp_c.py` compares every call with ``daqp.solve``):

* the rows normalised here, eight at a time in the lanes of a vector, each row's squares
  summed in DAQP's order (`LDP_C`'s ``normalize``; no fused multiply-add, as in the wheel's
  build, which has none): DAQP's ``M`` and ``scaling`` to the bit; eight rows the caller
  marks as the same bits as the last solve's (`LeastDistanceWorkspace.step`'s ``same``) are
  left as they are, if that solve normalised them here (DAQP's solve only reads ``M`` and
  ``scaling``; after a fresh set-up every row is normalised again);
* the identity's factor kept (DAQP's diagonal ``RinvD``, ones: a set-up forms the same
  again from the same identity, and sets no state flag for it);
* the workspace's per-solve fields reset as ``allocate_daqp_workspace`` sets them (iterate
  zero, no active set, no soft slack, no state);
* then DAQP's own ``daqp_update_ldp`` with the set-up's mask less the parts done above
  (senses, bound checks, the unconstrained-optimum check, the bounds' scaling, the working
  set from the senses), and ``daqp_solve``: ~20 us in all for the MPC's rows.

Anything off that path goes through DAQP's own set-up on a fresh workspace, exactly as
``daqp_quadprog`` does it: the first solve, another number of variables or more rows, a row
with a sum of squares below DAQP's zero tolerance or not finite (DAQP's zero-row handling),
equalities DAQP would eliminate (``daqp_eq_wanted``), a set-up or update that failed (the
exit flag then says so, and no solve runs, as in ``daqp.solve``), and a solve that left
anything but the plain dual active-set method's state in the workspace (equality
elimination, branch and bound, proximal iterations, a hierarchy, an AVI).

`LeastDistanceWorkspace.step` runs `wbc.solvers.DaqpBackend`'s numpy around a solve in the
same call (its docstring), with numpy's own BLAS for the products.

The warm start is the wrapper's: the senses (0, and 5 for the equalities from
``first_equality`` on) marked active by ``daqp_dual_init_active`` from ``dual_start``.

The C is built on DAQP 0.11.0's structures and calls the functions of the loaded ``daqp``
extension module through pointers handed over by ctypes (`wbc.solvers.daqp_api`);
`ldp_library` loads it only for the version they were copied from (`DAQP_VERSION`) and after
a check against ``daqp.solve`` on small problems (the same bits or no library).
"""

from __future__ import annotations

import ctypes
import functools
import logging
import weakref

import daqp
import numpy as np

from models.cbuild import address, load_shared
from wbc.solvers import ldp_step
from wbc.solvers.daqp_api import DAQP_API_C, DAQP_VERSION, bind_daqp, daqp_version
from wbc.solvers.ldp_step import STEP_C
from wbc.solvers.product_c import TRANSPOSE8_C

__all__ = ["LDP_C", "SIGNATURES", "LeastDistanceWorkspace", "ldp_library"]

_log = logging.getLogger(__name__)

_p, _lg = ctypes.c_void_p, ctypes.c_long
SIGNATURES = {  # `LDP_C`'s functions: (argtypes, restype)
    "daqp_bind": ([_p], None),
    "ldp_new": ([ctypes.c_double, ctypes.c_int], _p),
    "ldp_free": ([_p], None),
    "ldp_solve": ([_p, _lg, _lg, _lg, _p, _p, _p, _p, _p, _p, _p], ctypes.c_int),
    "ldp_step": ([_p, _p, _p, _lg, _lg, _lg, _lg, *[_p] * 21], ctypes.c_int)}

LDP_C = DAQP_API_C + r"""
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <time.h>
#if defined(__AVX512F__)
#include <immintrin.h>
#endif
""" + TRANSPOSE8_C + r"""
typedef struct {
  DAQPSettings settings;
  DAQPWorkspace work;
  int live;     /* work holds a set-up workspace the next solve may keep */
  int valid;    /* the rows of work's M and scaling that `normalize` formed from the last
                   solve's A (0 after a fresh set-up or none) */
  int n, cap;   /* its variables, the rows its arrays hold */
  double* eye;  /* the identity, n x n */
  int* sense;   /* the problem's senses, cap long */
} Ldp;

static void drop(Ldp* c) {
  if (!c->live) return;
  c->work.settings = NULL; /* the settings are c's */
  daqp.free_daqp_workspace(&c->work);
  daqp.free_daqp_ldp(&c->work);
  c->live = 0;
  c->valid = 0;
}

void* ldp_new(double primal_tol, int iter_limit) {
  Ldp* c = calloc(1, sizeof(Ldp));
  if (!c) return NULL;
  daqp.daqp_default_settings(&c->settings);
  c->settings.primal_tol = primal_tol;
  c->settings.iter_limit = iter_limit;
  return c;
}

void ldp_free(void* p) {
  Ldp* c = p;
  if (!c) return;
  drop(c);
  free(c->eye);
  free(c->sense);
  free(c);
}

/* Rows [0, m) of A (n long) times d, as daqp_update_M forms DAQP's M, normalised as
   daqp_normalize_M does it: scaling[i] = 1 / sqrt(sum_j M_ij^2), the squares added in j's
   order, and M_i *= scaling[i]. Eight rows below `valid` that same[] marks (the bits of
   the rows that formed M and scaling there; same NULL: none) are left as they are.
   Returns 0; -1 if a row's sum is below zero_tol or not finite (M and scaling then partly
   written): DAQP's own pass handles it. */
static int normalize(const double* A, const double* d, long n, long m, double zero_tol,
                     double* M, double* scaling, const unsigned char* same, long valid) {
  for (long i0 = 0; i0 < m; i0 += 8) {
    const long used = m - i0 < 8 ? m - i0 : 8;
    if (same && i0 + 8 <= valid && i0 + 8 <= m) {
      uint64_t all;  /* eight flags of 0 or 1 */
      memcpy(&all, same + i0, sizeof all);
      if (all == 0x0101010101010101ULL) continue;
    }
    double s[8], scale[8];
#if defined(__AVX512F__)
    /* Lane l sums row i0 + l; the rows past m repeat the last one (their sums unused). An
       8 x 8 block of the rows is transposed in registers and its columns added in order;
       the columns past n load as zeros, whose squares (+0) leave every sum as it is. */
    const double* r[8];
    for (int l = 0; l < 8; ++l) r[l] = A + (i0 + (l < used ? l : used - 1)) * n;
    __m512d acc = _mm512_setzero_pd();
    for (long j = 0; j < n; j += 8) {
      const __mmask8 k = n - j >= 8 ? 0xFF : (__mmask8)((1u << (n - j)) - 1);
      const __m512d dj = _mm512_maskz_loadu_pd(k, d + j);
      __m512d v[8];
      for (int l = 0; l < 8; ++l) v[l] = _mm512_mul_pd(_mm512_maskz_loadu_pd(k, r[l] + j), dj);
      __m512d c[8];  /* c[q]: column j + q of the eight rows */
      transpose8(v, c);
      for (int q = 0; q < 8; ++q) acc = _mm512_add_pd(acc, _mm512_mul_pd(c[q], c[q]));
    }
    _mm512_storeu_pd(s, acc);
#else
    for (long l = 0; l < used; ++l) {
      const double* a = A + (i0 + l) * n;
      double sum = 0;
      for (long j = 0; j < n; ++j) {
        const double t = a[j] * d[j];
        sum += t * t;
      }
      s[l] = sum;
    }
#endif
    for (long l = 0; l < used; ++l) {
      if (!(s[l] >= zero_tol) || !isfinite(s[l])) return -1;
      scale[l] = 1 / sqrt(s[l]);
      scaling[i0 + l] = scale[l];
    }
    for (long l = 0; l < used; ++l) {
      const double* a = A + (i0 + l) * n;
      double* out = M + (i0 + l) * n;
      for (long j = 0; j < n; ++j) out[j] = (a[j] * d[j]) * scale[l];
    }
  }
  return 0;
}

/* Grows the row arrays of a set-up workspace to cap rows (DAQP frees them with free()). */
static int grow(Ldp* c, int cap) {
  DAQPWorkspace* w = &c->work;
  double *M = realloc(w->M, (size_t)cap * w->n * sizeof(double));
  if (M) w->M = M;
  double *Mu = realloc(w->Mu, (size_t)cap * sizeof(double));
  if (Mu) w->Mu = Mu;
  double *sc = realloc(w->scaling, (size_t)cap * sizeof(double));
  if (sc) w->scaling = sc;
  double *du = realloc(w->dupper, (size_t)cap * sizeof(double));
  if (du) w->dupper = du;
  double *dl = realloc(w->dlower, (size_t)cap * sizeof(double));
  if (dl) w->dlower = dl;
  int *se = realloc(w->sense, (size_t)cap * sizeof(int));
  if (se) w->sense = se;
  return M && Mu && sc && du && dl && se ? cap : w->m;
}

/* Whether the solve left the workspace as the plain dual active-set method does. */
static int plain(const DAQPWorkspace* w) {
  return w->eq == NULL && w->bnb == NULL && w->avi == NULL && w->hierarchy == NULL &&
         w->n_prox == 0 && w->v == NULL && w->Rinv == NULL && w->RinvD != NULL && w->ms == 0;
}

/* daqp.solve(eye(n), None, A, bu, bl, sense, dual_start=dual, primal_tol, iter_limit)
   with sense 0 for rows [0, first_eq) and 5 after, A (m x n) C-contiguous, m >= 1: x (n),
   lam (m, written if the exit flag is positive), out = {exit flag, iterations, path}
   (path: 1 the kept workspace, 0 a fresh set-up, -1 no solve: the set-up failed); same:
   `normalize`'s (NULL: none). Returns 0; -1 out of memory. */
static int solve_rows(void* p, long n, long m, long first_eq, const double* A,
                      const double* bu, const double* bl, const double* dual, double* x,
                      double* lam, int* out, const unsigned char* same) {
  Ldp* c = p;
  DAQPWorkspace* w = &c->work;
  if (c->n != n) {
    drop(c);
    free(c->eye);
    c->eye = calloc((size_t)n * n, sizeof(double));
    if (!c->eye) { c->n = 0; return -1; }
    for (long i = 0; i < n; ++i) c->eye[i * n + i] = 1.0;
    c->n = (int)n;
  }
  if (c->cap < m) {
    int* sense = realloc(c->sense, (size_t)m * sizeof(int));
    if (!sense) return -1;
    c->sense = sense;
  }
  for (long i = 0; i < m; ++i) c->sense[i] = i < first_eq ? 0 : EQUALITY;
  DAQPProblem qp = {(int)n, (int)m, 0, c->eye, NULL, (double*)A, (double*)bu, (double*)bl,
                    c->sense, NULL, 0, 0};
  if (dual) daqp.daqp_dual_init_active(&qp, (double*)dual);
  DAQPResult res = {x, lam, 0, 0, 0, 0, 0, 0, 0};
  const int mask = UPDATE_unconstrained | UPDATE_eliminate | UPDATE_d | UPDATE_sense;
  int kept = 0;
  if (c->live && m <= c->cap) {
    /* What a set-up leaves of the Hessian stays; the rest as allocate_daqp_workspace and
       daqp_update_M leave it, then DAQP's update of the senses and bounds. */
    memcpy(w->sense, c->sense, m * sizeof(int));
    w->m = (int)m;
    kept = !daqp.daqp_eq_wanted(w, &qp, mask) &&
           normalize(A, w->RinvD, n, m, c->settings.zero_tol, w->M, w->scaling, same,
                     c->valid) == 0;
    c->valid = kept ? (int)m : 0;
  }
  if (kept) {
    w->state = 0; /* daqp_update_R's flags for the identity: none (a set-up's start) */
    w->u = w->x;
    memset(w->u, 0, n * sizeof(double));
    w->soft_slack = 0;
    w->outer_iter = 1;
    w->timer = NULL;
    daqp.reset_daqp_workspace(w);
    const int flag = daqp.daqp_update_ldp(mask, w, &qp);
    if (flag < 0) {
      drop(c); /* as a failed set-up: no solve */
      out[0] = flag, out[1] = 0, out[2] = -1;
      return 0;
    }
  } else {
    drop(c);
    memset(w, 0, sizeof *w);
    w->settings = &c->settings;
    double setup_time = 0;
    const int flag = daqp.setup_daqp_main(&qp, w, &setup_time,
                                          UPDATE_unconstrained | UPDATE_eliminate);
    if (flag < 0) { /* DAQP freed the workspace */
      out[0] = flag, out[1] = 0, out[2] = -1;
      return 0;
    }
    c->live = 1;
    c->cap = (int)m;
  }
  daqp.daqp_solve(&res, w);
  out[0] = res.exitflag, out[1] = res.iter, out[2] = kept;
  if (!plain(w)) {
    drop(c);
  } else if (!kept) {
    const int cap = (int)(m + m / 4);
    if (c->cap < cap) {
      int* sense = realloc(c->sense, (size_t)cap * sizeof(int));
      if (sense) {
        c->sense = sense;
        c->cap = grow(c, cap);
      }
    }
  }
  return 0;
}

int ldp_solve(void* p, long n, long m, long first_eq, const double* A, const double* bu,
              const double* bl, const double* dual, double* x, double* lam, int* out) {
  return solve_rows(p, n, m, first_eq, A, bu, bl, dual, x, lam, out, NULL);
}

""" + STEP_C


@functools.cache
def ldp_library():
    """`LDP_C` compiled, loaded and bound to the ``daqp`` module's C functions, once per process.

    None (logged) without a compiler, for a ``daqp`` other than `DAQP_VERSION`, without its
    symbols, or when the check against ``daqp.solve`` (`_self_check`) finds other bits: the
    backend then calls ``daqp.solve``.
    """
    version = daqp_version()
    if version != DAQP_VERSION:
        _log.warning("daqp %s, not %s: DAQP through daqp.solve", version, DAQP_VERSION)
        return None
    lib = load_shared(LDP_C, "daqp_ldp", SIGNATURES, "daqp.solve", opt="-O3")
    if lib is None:
        return None
    try:
        bind_daqp(lib)
    except (OSError, AttributeError) as exc:
        _log.warning("daqp's C functions not found (%s): DAQP through daqp.solve", exc)
        return None
    if not _self_check(lib):
        _log.warning("the kept DAQP workspace disagrees with daqp.solve: DAQP through "
                     "daqp.solve")
        return None
    return lib


class LeastDistanceWorkspace:
    """DAQP's least-distance problem on a workspace kept from solve to solve (module docstring).

    Args:
        primal_tol: DAQP's primal feasibility tolerance.
        iter_limit: DAQP's cap on active-set iterations.
        lib: `ldp_library`'s library (None: this process's).

    Raises:
        OSError: No library (`ldp_library` returned None) or no memory for the workspace.

    Not shared between threads (each `wbc.solvers.DaqpBackend` makes its own).
    """

    def __init__(self, primal_tol: float, iter_limit: int, lib=None):
        lib = ldp_library() if lib is None else lib
        if lib is None:
            raise OSError("no compiled DAQP workspace (see the log)")
        self._ctx = lib.ldp_new(float(primal_tol), int(iter_limit))
        if not self._ctx:
            raise OSError("no memory for a DAQP workspace")
        weakref.finalize(self, lib.ldp_free, self._ctx)
        self._solve = functools.partial(lib.ldp_solve, self._ctx)
        self._out = np.zeros(3, dtype=np.intc)
        self._out_address = self._out.ctypes.data
        self._lib, self._settings = lib, (float(primal_tol), int(iter_limit))
        self.kept = False  # the last solve's path: the kept workspace, else a fresh set-up
        self._step = functools.partial(lib.ldp_step, self._ctx)
        self._step_out = np.zeros(5, dtype=np.intc)
        self._step_out_address = self._step_out.ctypes.data
        self._time = np.zeros(1)
        self._time_address = self._time.ctypes.data
        self._scratch = (0, 0, None, ())  # `step`'s vectors: (n, rows, buffer, addresses)

    step = ldp_step.step

    def __deepcopy__(self, memo) -> LeastDistanceWorkspace:
        """A workspace of its own, empty: its first solve sets DAQP up (the same bits)."""
        new = LeastDistanceWorkspace(*self._settings, self._lib)
        memo[id(self)] = new
        return new

    def solve(self, a: np.ndarray, upper: np.ndarray, lower: np.ndarray,
              first_equality: int, dual: np.ndarray | None
              ) -> tuple[np.ndarray, np.ndarray, int, int]:
        """``daqp.solve(eye, None, a, upper, lower, sense, dual_start=dual, ...)``'s bits.

        Args:
            a: The rows, float64 (m, n), C-contiguous, m >= 1.
            upper: Their upper bounds, float64 (m,), contiguous.
            lower: Their lower bounds, float64 (m,), contiguous.
            first_equality: The rows from this one on are equalities (DAQP's sense 5).
            dual: The warm start's multipliers, float64 (m,), contiguous; None: cold.

        Returns:
            ``(x, lam, exit flag, iterations)``: ``x`` (n,) and ``lam`` (m,) new arrays,
            ``lam`` written only for a positive exit flag, neither if the set-up failed
            (``daqp.solve`` leaves them unwritten too).

        Raises:
            MemoryError: No memory for the workspace.
        """
        m, n = a.shape
        x = np.empty(n)
        lam = np.empty(m)
        if self._solve(n, m, first_equality, address(a), address(upper), address(lower),
                       None if dual is None else address(dual), address(x), address(lam),
                       self._out_address) != 0:
            raise MemoryError("no memory for the DAQP workspace")
        out = self._out
        self.kept = bool(out[2] == 1)
        return x, lam, int(out[0]), int(out[1])


def _self_check(lib) -> bool:
    """``LeastDistanceWorkspace`` against ``daqp.solve`` on small problems: the same bits.

    Cold, warm and again warm on the kept workspace, with equalities and fewer rows, of
    random least-distance problems (a structure or calling convention that differs, e.g. in
    another build, shows in the multipliers or the iterate).
    """
    rng = np.random.default_rng(7)
    n = 12
    work = LeastDistanceWorkspace(1e-7, 1000, lib)
    eye = np.eye(n)
    dual = None
    for m, first_eq in ((n + 30, n + 30), (n + 30, n + 28), (n + 20, n + 20), (n + 34, n + 34)):
        a = np.vstack([np.eye(n), rng.normal(size=(m - n, n))])
        inside = rng.uniform(-0.5, 0.5, n)  # a feasible point, away from the origin
        upper = np.r_[np.full(n, 1.0), a[n:] @ inside + rng.uniform(0.0, 1.0, m - n)]
        upper[n:n + 4] = a[n:n + 4] @ inside  # rows that bind
        lower = np.r_[np.full(n, -1.0), np.full(m - n, -1e20)]
        lower[first_eq:] = upper[first_eq:]
        for warm in (False, True):
            start = dual if warm and dual is not None and dual.size == m else None
            sense = np.zeros(m, dtype=np.intc)
            sense[first_eq:] = 5
            x, _, flag, info = daqp.solve(eye, None, a, upper, lower, sense, dual_start=start,
                                          primal_tol=1e-7, iter_limit=1000)
            x2, lam2, flag2, iterations2 = work.solve(a, upper, lower, first_eq, start)
            if not (flag == flag2 and info["iterations"] == iterations2 and flag > 0
                    and x.tobytes() == x2.tobytes()
                    and info["lam"].tobytes() == lam2.tobytes()):
                return False
            dual = info["lam"]
    return True
