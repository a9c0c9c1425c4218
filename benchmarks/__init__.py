"""Benchmarks that print their figures and write them to ``<out>/<name>.json``.

Speed and accuracy targets live here, never in tests: ``make bench`` or ``wbc bench``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

# One BLAS thread, as the ``wbc`` command runs (see `wbc_hdmm`): set before numpy loads.
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

BENCHES = ("simulator", "estimator", "controller", "observer", "qp")
# Long reproductions, run only when named (``--only``): not part of ``make bench``.
EXTRA = ("ticks",)
# The file each benchmark writes, when it is not ``<name>.json``.
FILES = {"qp": "qp_solvers"}


def _machine_info() -> dict:
    return {"python": platform.python_version(), "machine": platform.machine(),
            "processor": platform.processor() or platform.machine(),
            "cpus": os.cpu_count(), "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS"),
            "date": time.strftime("%Y-%m-%d %H:%M:%S")}


def _run_one(name: str, out: Path) -> dict:
    if name == "simulator":
        from benchmarks.bench_simulator import run
    elif name == "estimator":
        from benchmarks.bench_estimator import run
    elif name == "controller":
        from benchmarks.bench_wbc import run
    elif name == "observer":
        from benchmarks.bench_observer import run
    elif name == "qp":
        from benchmarks.bench_qp_solvers import run
    elif name == "ticks":
        from benchmarks.bench_ticks import run
    else:
        raise ValueError(f"unknown benchmark '{name}'; valid: {', '.join(BENCHES + EXTRA)}")
    result = run(out)
    result["host"] = _machine_info()
    (out / f"{FILES.get(name, name)}.json").write_text(json.dumps(result, indent=2, default=float))
    return result


def main(argv: list[str] | None = None) -> dict:
    """Run the benchmarks; print and write their figures."""
    p = argparse.ArgumentParser(prog="python -m benchmarks")
    p.add_argument("--out", default="out/bench")
    p.add_argument("--only", default=None, choices=BENCHES + EXTRA)
    args = p.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    results = {}
    for name in ([args.only] if args.only else BENCHES):
        print(f"== benchmark: {name}", flush=True)
        results[name] = _run_one(name, out)
        for k, v in results[name].items():
            if k != "host":
                print(f"   {k:40s} {v}")
    if not args.only:
        from benchmarks.targets import format_table, targets

        rows = targets(results)
        (out / "targets.json").write_text(json.dumps(rows, indent=2, default=float))
        print("== real-time targets (ratios to anchors measured in this run)")
        print("\n".join(format_table(rows)))
    print(f"wrote {out}/*.json")
    return results
