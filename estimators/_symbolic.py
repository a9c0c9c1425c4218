"""CasADi graph of the estimator, compiled to C (the fast path), with exact derivatives.

The recursion of `estimators.tree` and the system of `estimators.full_dynamics` are run with
`CasadiOps`, which builds a CasADi SX expression of the very same code. Three functions of one
flat input vector (layout `Layout`) are made from it:

* ``nf_estimate``: normal forces, F_Xi, the system and its condition number;
* ``nf_constraint``: normal forces and their Jacobian with respect to the generalised
  accelerations ``a = [base_acceleration (6), qdd (13)]`` (exact: f_z is affine in ``a``);
* ``nf_derivatives``: the same plus the Jacobians with respect to ``q`` and ``qd``.

They are generated as C, compiled once with the system C compiler into a shared library kept
in a cache folder (``$WBC_HDMM_CACHE``, else ``$XDG_CACHE_HOME/wbc-hdmm``, else
``~/.cache/wbc-hdmm``) keyed by the hash of the generated source, and called through ctypes:
one call per state for `estimate`, one C loop per chunk of states for batches (threads over
chunks, ctypes releases the GIL). Without a working compiler the same CasADi functions run in
CasADi's virtual machine (slower, same numbers).
"""

from __future__ import annotations

import ctypes
import logging
import os
import subprocess
import tempfile
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import casadi as ca
import numpy as np

from estimators._kernel_calls import BATCH_C, Compiled, Interpreted
from estimators.full_dynamics import normal_force_system
from estimators.tree import TreeModel
from models.cbuild import compile_shared
from models.coordinates import N_INDEPENDENT

__all__ = ["CasadiOps", "Kernels", "Layout", "build_kernels", "checked_row", "row_major"]

_log = logging.getLogger(__name__)


def _sx(v):
    return v if isinstance(v, (ca.SX, ca.MX, ca.DM)) else ca.SX(float(v))


class CasadiOps:
    """Symbolic backend of the recursion: CasADi SX, vectors as (n, 1) columns."""

    cos = staticmethod(ca.cos)
    sin = staticmethod(ca.sin)
    sqrt = staticmethod(ca.sqrt)
    acos = staticmethod(ca.acos)
    fabs = staticmethod(ca.fabs)

    @staticmethod
    def const(x):
        """A constant (DM) matrix or column."""
        return ca.DM(np.asarray(x, float))

    @staticmethod
    def vcat(parts):
        """Stack scalars and columns into one column."""
        return ca.vertcat(*[_sx(p) for p in parts])

    @staticmethod
    def rows(rows):
        """Matrix from a list of rows of scalars."""
        return ca.vertcat(*[ca.horzcat(*[_sx(v) for v in r]) for r in rows])

    @staticmethod
    def hcat(cols):
        """Matrix from columns."""
        return ca.horzcat(*cols)

    @staticmethod
    def vstack(mats):
        """Stack matrices vertically."""
        return ca.vertcat(*mats)

    dot = staticmethod(ca.dot)
    cross = staticmethod(ca.cross)

    @staticmethod
    def inv(m):
        """Symbolic inverse (QR based, no pivoting: the systems here are well scaled)."""
        return ca.solve(m, ca.SX.eye(m.shape[0]))

    @staticmethod
    def norm_1(m):
        """Induced 1-norm (max column sum)."""
        return ca.mmax(ca.sum1(ca.fabs(m)))

    norm_2 = staticmethod(ca.norm_2)
    det3 = staticmethod(ca.det)

    @staticmethod
    def entry(v, i):
        """Scalar entry ``i`` of a column."""
        return v[i]

    @staticmethod
    def col(m, j):
        """Column ``j``."""
        return m[:, j]

    @staticmethod
    def skew(v):
        """Skew matrix of a 3-column."""
        return ca.skew(v)

    @staticmethod
    def adjoint_rp(r, p):
        """``Ad`` of the pose (r, p), twist order [v; w] (see `estimators.spatial`)."""
        z = ca.SX.zeros(3, 3)
        return ca.vertcat(ca.horzcat(r, ca.skew(p) @ r), ca.horzcat(z, r))

    @staticmethod
    def coadjoint_rp(r, p):
        """Wrench map of the pose (r, p): child wrench -> parent."""
        z = ca.SX.zeros(3, 3)
        return ca.vertcat(ca.horzcat(r, z), ca.horzcat(ca.skew(p) @ r, r))

    @staticmethod
    def ad(nu):
        """Lie bracket matrix."""
        w, v = ca.skew(nu[3:]), ca.skew(nu[:3])
        return ca.vertcat(ca.horzcat(w, v), ca.horzcat(ca.SX.zeros(3, 3), w))

    @staticmethod
    def ad_star(nu):
        """Dual Lie bracket ``-ad(nu)^T``."""
        w, v = ca.skew(nu[3:]), ca.skew(nu[:3])
        return ca.vertcat(ca.horzcat(w, ca.SX.zeros(3, 3)), ca.horzcat(v, w))


def _packed(fields) -> dict:
    """Consecutive positions of named fields: a slice per vector, an int per scalar (None)."""
    out, start = {}, 0
    for name, size in fields:
        out[name] = start if size is None else slice(start, start + size)
        start += 1 if size is None else size
    out["size"] = start
    return out


class Layout:
    """Positions in the flat kernel input (one row per state) and in each kernel's output.

    Computed from the field sizes, in this order. State: base rotation (9, row-major world <-
    fb), base twist (6), base acceleration (6), q, qd, qdd (13 each). Contacts: measured
    points (12, row-major (4, 3)), use-measured flags (4), measured forces in fb (12).
    Selectors (`full_dynamics.Selectors`): mask (4), height weights (4), s_dbeta, s_cylinder,
    lost (4). Parameters: D, beta, suspension forces (2), the payload's mass (a run-time
    input: `TreeModel.dynamics`; one kernel serves every payload). Outputs of
    ``nf_estimate``: x (4), F_Xi (6), A (3x4), b (3), condition, contact points (4x3),
    residual (3), checksum; of ``nf_constraint``: x, d x / d a (4x19 row-major), d b / d a
    (3x19), g0 = x - (dx/da) a (4), condition, checksum; of ``nf_derivatives``: x, d x / d a,
    d x / d q (4x13), d x / d qd (4x13), g0, condition, checksum. The checksum is the sum of
    the row's other outputs: finite exactly when all of them are, so a caller tests one
    number.
    """

    def __init__(self):
        n = N_INDEPENDENT
        g = 6 + n
        inputs = _packed([("rotation", 9), ("twist", 6), ("acceleration", 6), ("q", n),
                          ("qd", n), ("qdd", n), ("points", 12), ("use_measured", 4),
                          ("force", 12), ("mask", 4), ("height_weights", 4),
                          ("s_dbeta", None), ("s_cylinder", None), ("lost", 4), ("d", None),
                          ("beta", None), ("suspension_force", 2), ("payload_mass", None)])
        estimate = _packed([("out_x", 4), ("out_xi", 6), ("out_a", 12), ("out_b", 3),
                            ("out_cond", None), ("out_points", 12), ("out_residual", 3),
                            ("out_sum", None)])
        estimate["out_size"] = estimate.pop("size")
        constraint = _packed([("con_x", 4), ("con_g", 4 * g), ("con_jb", 3 * g),
                              ("con_g0", 4), ("con_cond", None), ("con_sum", None)])
        derivatives = _packed([("der_x", 4), ("der_a", 4 * g), ("der_q", 4 * n),
                               ("der_qd", 4 * n), ("der_g0", 4), ("der_cond", None),
                               ("der_sum", None)])
        constraint["con_size"] = constraint.pop("size")
        derivatives["der_size"] = derivatives.pop("size")
        for part in (inputs, estimate, constraint, derivatives):
            self.__dict__.update(part)


LAYOUT = Layout()


def row_major(m) -> ca.SX:
    """The entries of matrix ``m`` as one column, row after row."""
    return ca.reshape(m.T, -1, 1)


def checked_row(*parts) -> ca.SX:
    """The parts as one dense column, then their sum (the checksum, see `Layout`).

    Dense: generated C writes only structural nonzeros, and the ctypes callers read fixed
    row layouts. The checksum is finite exactly when every other entry is.
    """
    body = ca.densify(ca.vertcat(*parts))
    return ca.vertcat(body, ca.sum1(body))


def build_kernels(tree: TreeModel) -> dict[str, ca.Function]:
    """The three CasADi functions of the estimator for ``tree`` (see the module docstring)."""
    lay = LAYOUT
    z = ca.SX.sym("z", lay.size)
    rot = ca.reshape(z[lay.rotation], 3, 3).T  # row-major input
    twist, acc = z[lay.twist], z[lay.acceleration]
    q, qd, qdd = z[lay.q], z[lay.qd], z[lay.qdd]
    pts = [z[lay.points.start + 3 * k: lay.points.start + 3 * k + 3] for k in range(4)]
    frc = [z[lay.force.start + 3 * k: lay.force.start + 3 * k + 3] for k in range(4)]
    use = z[lay.use_measured]
    ops = CasadiOps
    dyn = tree.dynamics(ops, rot, twist, acc, q, qd, qdd, payload_mass=z[lay.payload_mass])
    out = normal_force_system(
        ops, tree, dyn, rot, pts, use, frc, z[lay.mask], z[lay.height_weights],
        z[lay.s_dbeta], z[lay.s_cylinder], z[lay.lost], z[lay.d], z[lay.beta],
        z[lay.suspension_force])
    x = out["x"]
    residual = out["A"] @ x - out["b"]
    est = ca.vertcat(x, out["xi"], ca.reshape(out["A"].T, -1, 1), out["b"], out["cond"],
                     *out["points"], residual)
    a_sym = ca.vertcat(acc, qdd)
    ja = ca.jacobian(x, a_sym)
    jq = ca.jacobian(x, q)
    jqd = ca.jacobian(x, qd)
    jb = ca.jacobian(out["b"], a_sym)
    flat, row = row_major, checked_row
    g0 = x - ja @ a_sym

    return {
        "nf_estimate": ca.Function("nf_estimate", [z], [row(est)]),
        "nf_constraint": ca.Function("nf_constraint", [z],
                                     [row(x, flat(ja), flat(jb), g0, out["cond"])]),
        "nf_derivatives": ca.Function("nf_derivatives", [z],
                                      [row(x, flat(ja), flat(jq), flat(jqd), g0,
                                           out["cond"])]),
    }


def kernel_source(fun: ca.Function) -> str:
    """The C source of ``fun``: CasADi's generated code and the batch loop (`BATCH_C`)."""
    name = fun.name()
    with tempfile.TemporaryDirectory() as tmp:
        cg = ca.CodeGenerator(name + ".c", {"with_header": False, "verbose": False})
        cg.add(fun)
        cg.generate(tmp + os.sep)
        src = Path(tmp, name + ".c").read_text()
    return src + BATCH_C.format(name=name, sz_arg=max(fun.sz_arg(), 1),
                                sz_res=max(fun.sz_res(), 1), n_in=fun.size1_in(0),
                                n_out=fun.size1_out(0))


class Kernels:
    """The estimator's compiled (or interpreted) kernels for one tree.

    Each kernel is compiled into its own library on first use (``nf_estimate`` in under a
    second; the large derivative kernel at ``-O1`` in a few seconds), then cached on disk.

    Args:
        tree: The tree model.
        compile: Try to compile with the C compiler (``CC``, default ``cc``).

    Attributes:
        compiled: True while the kernels run as compiled C (False after a failed compile).
        libraries: Kernel name -> path of its shared library.
    """

    _registry: dict = {}
    _lock = threading.Lock()
    _OPT = {"nf_estimate": "-O2", "nf_constraint": "-O2", "nf_derivatives": "-O1"}

    def __init__(self, tree: TreeModel, compile: bool = True):
        self.functions = build_kernels(tree)
        self.libraries: dict[str, Path] = {}
        self.compiled = compile and self._try_compile("nf_estimate")
        self._kernels: dict = {}
        self._pool: ThreadPoolExecutor | None = None
        self._build_lock = threading.Lock()

    def _try_compile(self, name: str) -> bool:
        try:
            self.libraries[name] = self._compile(self.functions[name], self._OPT[name])
            return True
        except (OSError, subprocess.SubprocessError) as exc:
            _log.warning("estimator kernel %s not compiled (%s); using CasADi's VM", name, exc)
            return False

    def kernel(self, name: str):
        """The callable kernel ``name`` (compiled on first use)."""
        k = self._kernels.get(name)
        if k is None:
            with self._build_lock:
                k = self._kernels.get(name)
                if k is None:
                    fun = self.functions[name]
                    if self.compiled and (name in self.libraries or self._try_compile(name)):
                        k = Compiled(ctypes.CDLL(str(self.libraries[name])), fun)
                    else:
                        k = Interpreted(fun)
                    self._kernels[name] = k
        return k

    @classmethod
    def for_tree(cls, tree: TreeModel, compile: bool = True) -> Kernels:
        """Kernels shared by every estimator of a machine with the same description.

        Keyed by the description's content (`Machine.fingerprint`): two equal machines share
        the kernels, a changed number gets its own.
        """
        key = (tree.machine.fingerprint, compile)
        with cls._lock:
            kernels = cls._registry.get(key)
            if kernels is None:
                kernels = cls._registry[key] = cls(tree, compile)
        return kernels

    def source(self, name: str) -> str:
        """The C source of kernel ``name``: CasADi's generated function and the batch loop."""
        return kernel_source(self.functions[name])

    @staticmethod
    def _compile(fun: ca.Function, opt: str) -> Path:
        return compile_shared(kernel_source(fun), fun.name(), opt)

    def single(self, name: str):
        """(input buffer, output buffer, call) of kernel ``name`` for this thread."""
        k = self.kernel(name)
        inp, out = k.buffers()
        return inp, out, k.bound_call()

    def pool(self, threads: int) -> ThreadPoolExecutor:
        """A thread pool shared by batch evaluations (compiled kernels release the GIL)."""
        with self._build_lock:
            if self._pool is None or self._pool._max_workers != threads:
                self._pool = ThreadPoolExecutor(max_workers=threads)
            return self._pool

    def batch(self, name: str, inp: np.ndarray) -> np.ndarray:
        """Evaluate kernel ``name`` on every row of ``inp`` (n, n_in) -> (n, n_out)."""
        k = self.kernel(name)
        inp = np.ascontiguousarray(inp, dtype=float)
        out = np.empty((inp.shape[0], k.n_out))
        k.batch(inp, out)
        return out
