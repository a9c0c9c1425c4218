"""A small versioned corpus of the QPs the controllers build in closed loop.

`record_corpus` runs short closed loops (`scenarios.closed_loop.run_closed_loop`) and keeps
the QPs exactly as the controllers build them (``P, q, G, h, A, b, lb, ub``, dense,
float64), in blocks of consecutive ticks (a warm-start sequence), with a high-accuracy
reference solution of each (ProxQP, cold, ``eps_abs = 1e-10``). Nothing in production code
changes: the controllers' ``_build`` is wrapped for the duration of the runs.

Storage (``benchmarks/data/qp_corpus_v1.npz``): each field's distinct arrays once (the
MPC's Hessian and bounds repeat tick after tick), and per problem an index into them (-1:
None); a JSON header with the version, the commit it was recorded from and the runs.

    python -m benchmarks.qp_corpus --record     # regenerate the corpus
    python -m benchmarks.qp_corpus              # summarize it
"""

from __future__ import annotations

import argparse
import contextlib
import json
import subprocess
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import qpsolvers

from wbc.solvers import ProxQPWorkspace

__all__ = ["CORPUS_PATH", "DEFAULT_RUNS", "FIELDS", "VERSION", "QPCorpus", "load_corpus",
           "record_corpus", "reference_solve"]

VERSION = 1
CORPUS_PATH = Path(__file__).resolve().parent / "data" / f"qp_corpus_v{VERSION}.npz"
FIELDS = ("P", "q", "G", "h", "A", "b", "lb", "ub")
# (scenario, controller): the MPC on the two scenarios whose force constraint binds, and the
# whole-body QP (``tracking``).
DEFAULT_RUNS = (("swing-out", "mpc-full"), ("pick-in-motion", "mpc-full"),
                ("swing-out", "tracking"))
REFERENCE_EPS = 1e-10


@dataclass(frozen=True)
class QPCorpus:
    """The recorded QPs, in tick order.

    Attributes:
        problems: The QPs as built.
        records: Per problem: ``scenario``, ``controller``, ``block`` (consecutive ticks share
            one; a warm-start sequence), ``tick`` (the controller's tick), ``time`` [s].
        reference_x: High-accuracy solutions, one per problem.
        reference_objective: Their objectives ``x'Px/2 + q'x``.
        header: ``version``, ``commit``, ``runs``, ``reference``.
    """

    problems: list
    records: list
    reference_x: list
    reference_objective: np.ndarray
    header: dict

    def blocks(self) -> list[list[int]]:
        """Problem indices grouped by warm-start block, in tick order."""
        out: dict = {}
        for i, r in enumerate(self.records):
            out.setdefault((r["scenario"], r["controller"], r["block"]), []).append(i)
        return list(out.values())


def objective(problem: qpsolvers.Problem, x: np.ndarray) -> float:
    """``x' P x / 2 + q' x``."""
    return float(0.5 * x @ problem.P @ x + problem.q @ x)


def reference_solve(problem: qpsolvers.Problem) -> np.ndarray:
    """ProxQP, cold, at ``eps_abs = 1e-10`` (the soft MPC is feasible by construction).

    Raises:
        QPSolveError: ProxQP does not reach the tolerance.
    """
    ws = ProxQPWorkspace(eps_abs=REFERENCE_EPS, eps_rel=0.0, max_iter=10000,
                         warm_start=False, retry_infeasible=True)
    return ws.solve(problem).x


def _commit() -> str:
    root = Path(__file__).resolve().parents[1]
    try:
        sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True,
                             text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=root, capture_output=True, text=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return sha + ("-dirty" if dirty else "")


@contextlib.contextmanager
def _capturing(keep):
    """Wrap the controllers' ``_build``: ``keep(tick)`` says which ticks to store.

    Yields the list that receives ``(tick, time, problem)``; the tick counter restarts with
    every controller object.
    """
    from wbc.controllers.mpc import MpcController
    from wbc.controllers.tracking import WholeBodyQPController

    captured: list = []
    ticks: dict = {}
    originals = {cls: cls._build for cls in (MpcController, WholeBodyQPController)}

    def wrapper(original):
        def _build(self, ctx):
            problem = original(self, ctx)
            k = ticks.setdefault(id(self), 0)
            ticks[id(self)] = k + 1
            if keep(k):
                captured.append((k, float(ctx.state.time),
                                 qpsolvers.Problem(*(_copy(getattr(problem, f))
                                                     for f in FIELDS))))
            return problem
        return _build

    try:
        for cls, original in originals.items():
            cls._build = wrapper(original)
        yield captured
    finally:
        for cls, original in originals.items():
            cls._build = original


def _copy(a):
    return None if a is None else np.array(a, dtype=np.float64, copy=True)


def record_corpus(path: Path = CORPUS_PATH, runs=DEFAULT_RUNS, every: int = 200,
                  block: int = 15, first: int = 150, duration: float = 7.0,
                  seed: int = 0) -> QPCorpus:
    """Run the closed loops and write the corpus to ``path``.

    Args:
        path: The ``.npz`` file.
        runs: ``(scenario, controller)`` pairs.
        every: Ticks between the starts of two blocks.
        block: Consecutive ticks per block.
        first: The first block's first tick (after the settling and the first goal).
        duration: Closed-loop duration of each run [s].
        seed: Terrain seed.

    Returns:
        The corpus as written.
    """
    from scenarios.closed_loop import run_closed_loop

    problems, records = [], []
    for scenario, controller in runs:
        def keep(k):
            return k >= first and (k - first) % every < block
        with _capturing(keep) as captured:
            metrics = run_closed_loop(scenario, None, controller, seed=seed,
                                      duration=duration)
        print(f"   {scenario}/{controller}: {len(captured)} QPs, "
              f"{metrics['fallbacks']} fallbacks", flush=True)
        for k, t, problem in captured:
            problems.append(problem)
            records.append({"scenario": scenario, "controller": controller,
                            "block": (k - first) // every, "tick": k, "time": t})
    xs = [reference_solve(p) for p in problems]
    header = {"version": VERSION, "commit": _commit(), "seed": seed, "duration_s": duration,
              "every": every, "block": block, "first": first,
              "runs": [list(r) for r in runs],
              "reference": f"ProxQPWorkspace cold, eps_abs={REFERENCE_EPS:g}, eps_rel=0"}
    corpus = QPCorpus(problems, records, xs,
                      np.array([objective(p, x) for p, x in zip(problems, xs)]), header)
    save_corpus(corpus, path)
    return corpus


def save_corpus(corpus: QPCorpus, path: Path) -> None:
    """Write ``corpus`` (each field's distinct arrays once, compressed)."""
    arrays: dict = {}
    for f in FIELDS:
        pool: list = []
        index = np.full(len(corpus.problems), -1, dtype=np.int32)
        for i, p in enumerate(corpus.problems):
            a = getattr(p, f)
            if a is None:
                continue
            for j, b in enumerate(pool[-4:], start=max(len(pool) - 4, 0)):
                if a.shape == b.shape and np.array_equal(a, b):
                    index[i] = j
                    break
            else:
                index[i] = len(pool)
                pool.append(a)
        arrays[f"{f}_index"] = index
        for j, a in enumerate(pool):
            arrays[f"{f}_{j}"] = a
    for i, x in enumerate(corpus.reference_x):
        arrays[f"x_{i}"] = np.asarray(x, np.float64)
    arrays["reference_objective"] = corpus.reference_objective
    arrays["header"] = np.array(json.dumps({**corpus.header, "records": corpus.records}))
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **arrays)


def load_corpus(path: Path = CORPUS_PATH) -> QPCorpus:
    """Read a corpus written by `record_corpus`.

    Raises:
        FileNotFoundError: No file at ``path``.
        ValueError: Not a corpus of this version.
    """
    with np.load(path, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    header = json.loads(str(data["header"]))
    if header.get("version") != VERSION:
        raise ValueError(f"'{path}' is a QP corpus of version {header.get('version')}, "
                         f"expected {VERSION}")
    records = header.pop("records")
    problems = []
    for i in range(len(records)):
        fields = [None if data[f"{f}_index"][i] < 0 else data[f"{f}_{data[f'{f}_index'][i]}"]
                  for f in FIELDS]
        problems.append(qpsolvers.Problem(*fields))
    xs = [data[f"x_{i}"] for i in range(len(records))]
    return QPCorpus(problems, records, xs, data["reference_objective"], header)


def summary(corpus: QPCorpus, path: Path | None = None) -> dict:
    """Sizes and provenance of ``corpus``."""
    dims = sorted({(p.q.size, 0 if p.G is None else p.G.shape[0]) for p in corpus.problems})
    per_run: dict = {}
    for r in corpus.records:
        key = f"{r['scenario']}/{r['controller']}"
        per_run[key] = per_run.get(key, 0) + 1
    out = {"version": corpus.header["version"], "commit": corpus.header["commit"],
           "problems": len(corpus.problems), "blocks": len(corpus.blocks()),
           "per_run": per_run, "dims_n_by_rows": dims}
    if path is not None and Path(path).exists():
        out["file_bytes"] = Path(path).stat().st_size
    return out


def main(argv: list[str] | None = None) -> None:
    """``--record``: run the closed loops and write the corpus; else summarize it."""
    p = argparse.ArgumentParser(prog="python -m benchmarks.qp_corpus")
    p.add_argument("--record", action="store_true", help="run the closed loops and write it")
    p.add_argument("--path", type=Path, default=CORPUS_PATH)
    args = p.parse_args(argv)
    corpus = record_corpus(args.path) if args.record else load_corpus(args.path)
    print(json.dumps(summary(corpus, args.path), indent=2))


if __name__ == "__main__":
    main()
