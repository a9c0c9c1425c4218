"""`wbc.solvers.daqp_c`: the kept DAQP workspace gives ``daqp.solve``'s bits, call by call.

Oracle: ``daqp.solve`` itself (a fresh set-up of the same problem) on every call: the iterate,
the multipliers, the exit flag and the iteration count compared bit for bit, on the MPC's
real ticks, on the QP corpus through `DaqpBackend`, and on problems made to leave the kept
path (other sizes, zero rows, eliminated equalities, failures), for the host build and the
portable one.
"""

from __future__ import annotations

import ctypes

import daqp
import numpy as np
import pytest

from benchmarks.qp_corpus import load_corpus
from models.cbuild import compile_shared
from wbc.solvers import DaqpBackend, daqp_c
from wbc.solvers.daqp_api import DAQP_VERSION, bind_daqp, daqp_version
from wbc.solvers.daqp_c import SIGNATURES, LeastDistanceWorkspace, ldp_library

# The library is tested as built, not through `ldp_library` (whose check against daqp.solve
# would turn a wrong build into skipped tests).
pytestmark = pytest.mark.skipif(daqp_version() != DAQP_VERSION,
                                reason="another daqp than the one verified")


def _library(host: bool):
    lib = ctypes.CDLL(str(compile_shared(daqp_c.LDP_C, "daqp_ldp", "-O3", host=host)))
    for name, (argtypes, restype) in SIGNATURES.items():
        getattr(lib, name).argtypes, getattr(lib, name).restype = argtypes, restype
    bind_daqp(lib)
    return lib


@pytest.fixture(scope="module")
def builds():
    """`daqp_c.LDP_C` for this host's vector units and without them (the scalar sums)."""
    return {"host": _library(True), "portable": _library(False)}


def _reference(a, upper, lower, first_equality, dual, primal_tol=1e-7, iter_limit=1000):
    sense = np.zeros(upper.size, dtype=np.intc)
    sense[first_equality:] = 5
    x, _, flag, info = daqp.solve(np.eye(a.shape[1]), None, a, upper, lower, sense,
                                  dual_start=dual, primal_tol=primal_tol,
                                  iter_limit=iter_limit)
    return x, info["lam"], flag, int(info["iterations"])


def _assert_same(kept, reference, what="") -> None:
    """The same exit flag and iterations; the same bits of x once DAQP solved, of the
    multipliers once it found a solution (``daqp.solve`` leaves them unwritten otherwise)."""
    x, lam, flag, iterations = kept
    x_ref, lam_ref, flag_ref, iterations_ref = reference
    assert (flag, iterations) == (flag_ref, iterations_ref), what
    if iterations_ref:
        assert x.tobytes() == x_ref.tobytes(), what
    if flag_ref > 0:
        assert lam.tobytes() == lam_ref.tobytes(), what


def _problem(rng, n, m, first_equality=None):
    """Least-distance rows ``[I; random]`` with a feasible point inside, some rows binding."""
    first_equality = m if first_equality is None else first_equality
    a = np.vstack([np.eye(n), rng.normal(size=(m - n, n))])
    inside = rng.uniform(-0.5, 0.5, n)
    upper = np.r_[np.ones(n), a[n:] @ inside + rng.uniform(0.0, 1.0, m - n)]
    upper[n:n + 4] = a[n:n + 4] @ inside
    lower = np.r_[-np.ones(n), np.full(m - n, -1e20)]
    upper[first_equality:] = lower[first_equality:] = a[first_equality:] @ inside
    return a, upper, lower, first_equality


def test_the_mpc_ticks_solve_to_the_same_bits():
    """The MPC's QPs along a motion: `DaqpBackend` on the kept workspace against the same
    backend calling ``daqp.solve``, solve by solve (iterate, multipliers, iterations), and
    the kept path taken from the first solves on."""
    from benchmarks.bench_wbc import DT
    from models import build_reference_machine
    from testkit.plant import KinematicPlant, make_state
    from wbc import JointGoal, load_estimator, make_controller

    machine = build_reference_machine()
    controller = make_controller("mpc-full", machine,
                                 force_model=load_estimator(machine, "full"))
    st = make_state(machine)
    goal = st.q[2:9].copy()
    goal[3] += 0.3
    goal[0] -= 0.2
    controller.set_goal(JointGoal(crane=goal))
    plant = KinematicPlant(st, DT)
    kept, reference = DaqpBackend(), DaqpBackend()
    reference.kept_workspace = False
    assert kept.kept_workspace and not reference.kept_workspace
    paths = []
    for tick in range(40):
        p = controller.prepare(plant.state)
        a, b = kept.solve(p), reference.solve(p)
        assert a.x.tobytes() == b.x.tobytes(), tick
        assert a.iterations == b.iterations and a.warm_started == b.warm_started, tick
        for u, v in zip(kept.multipliers, reference.multipliers):
            assert u.tobytes() == v.tobytes(), tick
        paths.append(kept._workspace.kept if kept.form == "least-distance" else None)
        plant.apply(controller.step(plant.state))
    assert paths.count(True) >= 35


def test_the_corpus_solves_to_the_same_bits():
    """The QP corpus's blocks (the MPC's and the whole-body QP's Hessians, cold and warm
    starts, rows screened in and out): the same solutions and multipliers as with
    ``daqp.solve``."""
    corpus = load_corpus()
    kept, reference = DaqpBackend(), DaqpBackend()
    reference.kept_workspace = False
    n_kept = 0
    for block in corpus.blocks():
        kept.reset()
        reference.reset()
        for i in block:
            p = corpus.problems[i]
            a, b = kept.solve(p), reference.solve(p)
            assert a.x.tobytes() == b.x.tobytes(), i
            assert a.iterations == b.iterations, i
            for u, v in zip(kept.multipliers, reference.multipliers):
                assert u.tobytes() == v.tobytes(), i
            n_kept += kept.form == "least-distance" and kept._workspace.kept
    assert n_kept > 0


@pytest.mark.parametrize("build", ["host", "portable"])
def test_sizes_warm_starts_and_fallbacks_keep_the_bits(build, builds):
    """Rows growing past the kept arrays and shrinking, equalities, warm and cold starts,
    and the problems that leave the kept path (a zero row, equalities DAQP eliminates,
    crossed bounds, an infeasible problem, another number of variables)."""
    lib = builds[build]
    rng = np.random.default_rng(5)
    work = LeastDistanceWorkspace(1e-7, 1000, lib)
    paths = []

    def both(a, upper, lower, first_equality, dual, what):
        reference = _reference(a, upper, lower, first_equality, dual)
        _assert_same(work.solve(a, upper, lower, first_equality, dual), reference, what)
        paths.append(work.kept)
        return reference

    dual = None
    for n, m, n_eq in ((30, 90, 0), (30, 90, 0), (30, 70, 2), (30, 110, 0), (30, 140, 3),
                       (30, 100, 0), (20, 60, 0), (20, 60, 8), (20, 61, 0)):
        a, upper, lower, first = _problem(rng, n, m, m - n_eq)
        warm = dual if dual is not None and dual.size == m else None
        dual = both(a, upper, lower, first, None, (n, m, "cold"))[1]
        dual = both(a, upper, lower, first, dual, (n, m, "warm"))[1]
        upper[n + 4:] += 0.1  # the next tick's bounds
        both(a, upper, lower, first, warm if warm is not None else dual, (n, m, "again"))
        if n_eq == 8:  # 4 n_eq >= n: DAQP eliminates them, on a fresh set-up
            assert not any(paths[-3:])
    assert paths.count(True) >= 12 and paths.count(False) >= 5
    # Leaving the kept path, then coming back to it.
    a, upper, lower, first = _problem(rng, 20, 60)
    dual = both(a, upper, lower, first, None, "before")[1]
    infeasible, bounds = a.copy(), upper.copy()
    infeasible[25] = -infeasible[24]
    bounds[24:26] = -1.0  # a x <= -1 and a x >= 1
    assert both(infeasible, bounds, lower, first, dual, "infeasible")[2] < 0
    assert paths[-1]  # DAQP's iterations found it, on the kept workspace
    zero = a.copy()
    zero[30], bounds = 0.0, upper.copy()
    bounds[30] = 1.0  # 0 <= 1: DAQP sets the row aside
    assert both(zero, bounds, lower, first, dual, "a zero row")[2] == 1
    assert not paths[-1]
    crossed = lower.copy()
    crossed[40] = upper[40] + 1.0
    assert both(a, upper, crossed, first, dual, "crossed bounds")[3] == 0
    assert both(a, upper, lower, first, dual, "after")[2] == 1
    both(a, upper, lower, first, dual, "kept again")
    assert paths[-1]
    tight = LeastDistanceWorkspace(1e-7, 2, lib)  # the iteration cap
    for _ in range(2):
        _assert_same(tight.solve(a, upper, lower, first, None),
                     _reference(a, upper, lower, first, None, iter_limit=2), "cap")


def test_the_arrays_grow_by_a_quarter_past_the_most_rows(builds):
    """A set-up keeps room for a quarter more rows than it had: more rows set up afresh."""
    rng = np.random.default_rng(4)
    work = LeastDistanceWorkspace(1e-7, 1000, builds["host"])
    for m, kept in ((80, False), (100, True), (101, False), (126, True), (127, False),
                    (60, True)):
        a, upper, lower, first = _problem(rng, 20, m)
        _assert_same(work.solve(a, upper, lower, first, None),
                     _reference(a, upper, lower, first, None), m)
        assert work.kept == kept, m


def test_the_unconstrained_optimum_and_a_cold_start_after_it(builds):
    """Bounds around the origin: DAQP's unconstrained check ends the set-up early (no rows
    formed); the next problem binds, on the kept workspace."""
    rng = np.random.default_rng(9)
    work = LeastDistanceWorkspace(1e-7, 1000, builds["host"])
    a, upper, lower, first = _problem(rng, 16, 50)
    loose = np.abs(upper) + 1.0
    for bounds in ((loose, -loose), (upper, lower), (loose, -loose), (upper, lower)):
        _assert_same(work.solve(a, *bounds, first, None), _reference(a, *bounds, first, None))
    assert work.kept


def test_the_self_check_and_the_version_pin(monkeypatch, builds):
    """The library loads for the verified daqp and checks out; another version gets none."""
    assert ldp_library() is not None
    assert daqp_c._self_check(builds["host"]) and daqp_c._self_check(builds["portable"])
    monkeypatch.setattr(daqp_c, "daqp_version", lambda: "0.10.0")
    assert daqp_c.ldp_library.__wrapped__() is None


def test_the_backend_s_compiled_flag_switches_the_workspace():
    backend = DaqpBackend()
    assert backend.kept_workspace
    backend.compiled = False
    assert not backend.kept_workspace
    backend.compiled = True
    assert backend.kept_workspace
    assert not DaqpBackend(least_distance=False).kept_workspace


def test_a_copied_backend_solves_on_a_workspace_of_its_own():
    """``copy.deepcopy`` of a backend: another C workspace (not the same one freed twice),
    and both go on to the same bits."""
    import copy

    corpus = load_corpus()
    backend = DaqpBackend()
    for p in corpus.problems[:5]:
        backend.solve(p)
    twin = copy.deepcopy(backend)
    assert twin._workspace._ctx != backend._workspace._ctx
    for i, p in enumerate(corpus.problems[5:40]):
        assert backend.solve(p).x.tobytes() == twin.solve(p).x.tobytes(), i
