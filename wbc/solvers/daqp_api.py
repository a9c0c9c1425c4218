"""DAQP 0.11.0's C API as `wbc.solvers.daqp_c` reaches it: its structures and functions.

The ``daqp`` package is a Cython extension whose shared object exports DAQP's C functions
(``setup_daqp_main``, ``daqp_update_ldp``, ``daqp_solve``, ...). `DAQP_API_C` declares the
structures of DAQP 0.11.0 as its headers define them (``include/types.h``, ``api.h``,
``constants.h``, with ``c_float`` double; MIT licence, D. Arnström) and a table ``daqp`` of
pointers to the functions used, which `bind_daqp` fills from the module Python loaded (no
linking against an extension module). The declarations hold for `DAQP_VERSION` only: a
caller checks `daqp_version` first.
"""

from __future__ import annotations

import ctypes
import importlib.metadata

import daqp

__all__ = ["DAQP_API_C", "DAQP_FUNCTIONS", "DAQP_VERSION", "bind_daqp", "daqp_version"]

DAQP_VERSION = "0.11.0"  # the version whose headers `DAQP_API_C` copies

# The functions of the table ``daqp`` in `DAQP_API_C`, in its order.
DAQP_FUNCTIONS = ("setup_daqp_main", "daqp_update_ldp", "daqp_solve", "daqp_dual_init_active",
                  "daqp_eq_wanted", "free_daqp_workspace", "free_daqp_ldp",
                  "daqp_default_settings", "reset_daqp_workspace")

DAQP_API_C = r"""
#include <string.h>

/* DAQP 0.11.0's structures (include/types.h, include/api.h), c_float = double. */
typedef struct {
  int n, m, ms;
  double *H, *f, *A, *bupper, *blower;
  int* sense;
  int* break_points;
  int nh;
  int problem_type;
} DAQPProblem;

typedef struct {
  double primal_tol, dual_tol, zero_tol, pivot_tol, progress_tol;
  int cycle_tol, iter_limit;
  double fval_bound, eps_prox, eta_prox, rho_soft, rel_subopt, abs_subopt, sing_tol,
      refactor_tol, time_limit, w_soft;
  int eq_reduction, presolve;
} DAQPSettings;

typedef struct {
  DAQPProblem* qp;
  int n, m, ms;
  double *M, *dupper, *dlower, *Rinv, *v;
  int* sense;
  double *scaling, *RinvD;
  double *x, *xold, *lam, *lam_star, *u;
  double fval;
  double *L, *D, *xldl, *zldl;
  int reuse_ind;
  int* WS;
  int n_active, iterations, sing_ind;
  int* prox_mask;
  int n_prox;
  double soft_slack;
  DAQPSettings* settings;
  void* bnb;
  int outer_iter;
  void *hierarchy, *avi, *eq, *timer;
  double* Mu;
  double *rho_ls, *rho_us, *w_ls, *w_us;
  int state;
} DAQPWorkspace;

typedef struct {
  double *x, *lam;
  double fval, soft_slack;
  int exitflag, iter, nodes;
  double solve_time, setup_time;
} DAQPResult;

/* constants.h */
#define UPDATE_d 8
#define UPDATE_sense 16
#define UPDATE_unconstrained 64
#define UPDATE_eliminate 128
#define EQUALITY 5 /* DAQP_ACTIVE | DAQP_IMMUTABLE */

static struct {
  int (*setup_daqp_main)(DAQPProblem*, DAQPWorkspace*, double*, int);
  int (*daqp_update_ldp)(int, DAQPWorkspace*, DAQPProblem*);
  void (*daqp_solve)(DAQPResult*, DAQPWorkspace*);
  void (*daqp_dual_init_active)(DAQPProblem*, double*);
  int (*daqp_eq_wanted)(const DAQPWorkspace*, const DAQPProblem*, int);
  void (*free_daqp_workspace)(DAQPWorkspace*);
  void (*free_daqp_ldp)(DAQPWorkspace*);
  void (*daqp_default_settings)(DAQPSettings*);
  void (*reset_daqp_workspace)(DAQPWorkspace*);
} daqp;

void daqp_bind(void** functions) { memcpy(&daqp, functions, sizeof daqp); }

"""


def daqp_version() -> str | None:
    """The installed ``daqp``'s version (None: not installed as a distribution)."""
    try:
        return importlib.metadata.version("daqp")
    except importlib.metadata.PackageNotFoundError:
        return None


def bind_daqp(lib) -> None:
    """Fill the table ``daqp`` of a library built on `DAQP_API_C` (its ``daqp_bind``).

    Raises:
        OSError, AttributeError: The module cannot be opened, or lacks a function.
    """
    module = ctypes.CDLL(daqp.__file__)  # the extension Python loaded already
    table = (ctypes.c_void_p * len(DAQP_FUNCTIONS))(
        *(ctypes.cast(getattr(module, name), ctypes.c_void_p).value
          for name in DAQP_FUNCTIONS))
    lib.daqp_bind(table)
    lib.daqp_table = table  # the pointers live as long as the library
