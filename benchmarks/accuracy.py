"""Estimator accuracy on randomized open-loop runs, per sensor suite (held-out draws).

``python -m benchmarks.accuracy --draws 10 --master-seed 2026 --out out/accuracy`` runs
``draws`` open-loop traversals the project never tuned on: rough terrain (seed >= 100, largest
slope 5-26.7 deg) on a side slope of +-12 deg, each side's wheels on their own speed profile
(turning), the crane and suspension waving as in the paper's runs, payload 50-300 kg (not told
to the observer). Each run is scored like ``wbc estimate`` (`estimators.evaluate`), and
``summary.json`` gives, per suite and method, the mean error over the four-contact samples and
over the three-contact samples, with the observer's own errors. A failing draw is recorded,
never stops the others.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import traceback
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

__all__ = ["draw_open_loop", "main"]


def draw_open_loop(index: int, master_seed: int):
    """(scenario, machine, terrain seed, parameters) of draw ``index``."""
    from models import build_reference_machine
    from models.terrain import Terrain, rough, side_slope
    from scenarios.openloop import OpenLoopScenario

    rng = np.random.default_rng(np.random.SeedSequence([master_seed, 7, index]))
    seed = int(rng.integers(100, 2 ** 31 - 1))
    slope = float(rng.uniform(5.0, 26.7))
    side = float(rng.uniform(-12.0, 12.0))
    payload = float(rng.uniform(50.0, 300.0))
    b_right, b_left = (float(v) for v in rng.uniform(0.05, 0.3, 2) * math.pi)

    def terrain(_seed, slope=slope, side=side, seed=seed):
        base = rough(seed, slope, spacing=0.25)
        s = side_slope(side, spacing=0.25)
        return Terrain("rough_side_slope", base.heights + s.heights, base.x_range,
                       base.y_range, base.friction)

    sc = OpenLoopScenario(f"open-draw-{index:03d}", 20.0, terrain, (b_right, b_left),
                          description=f"draw {index} (master seed {master_seed})")
    params = {"terrain_seed": seed, "rough_slope_deg": slope, "side_slope_deg": side,
              "payload_kg": payload, "b_right": b_right, "b_left": b_left}
    return sc, build_reference_machine(payload_mass=payload), seed, params


def _run(index: int, master_seed: int, out: str) -> dict:
    from estimators.evaluate import evaluate_log
    from scenarios.openloop import run_open_loop

    row = {"index": index}
    try:
        sc, machine, seed, params = draw_open_loop(index, master_seed)
        row["parameters"] = params
        d = Path(out) / sc.name
        run_open_loop(sc, d, seed=seed, progress=False, machine=machine)
        rep = evaluate_log(d, plots=False, machine=machine)
        row["suites"] = {s: {m: v for m, v in e["methods"].items()} | (
            {"observer": e["observer"]} if "observer" in e else {})
            for s, e in rep["sensor_suites"].items()}
    except Exception as exc:  # noqa: BLE001 - recorded, the other draws go on
        row["error"] = f"{type(exc).__name__}: {exc}"
        row["traceback"] = traceback.format_exc(limit=6)
    return row


def _summary(rows: list[dict]) -> dict:
    out: dict = {"draws": len(rows), "failed": [r["index"] for r in rows if "error" in r]}
    ok = [r for r in rows if "suites" in r]
    for suite in ("oracle", "ideal", "realistic"):
        methods = {}
        for r in ok:
            for m, v in r["suites"].get(suite, {}).items():
                if m == "observer":
                    continue
                methods.setdefault(m, {"four_contact": [], "three_contact": []})
                for k in ("four_contact", "three_contact"):
                    if v[k] is not None:
                        methods[m][k].append(v[k])
        out[suite] = {m: {k: {"mean": float(np.mean(v)), "max": float(np.max(v)),
                              "runs": len(v)} if v else None for k, v in d.items()}
                      for m, d in methods.items()}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=10)
    ap.add_argument("--master-seed", type=int, default=2026)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", type=Path, default=Path("out/accuracy"))
    a = ap.parse_args(argv)
    a.out.mkdir(parents=True, exist_ok=True)
    rows = []
    with ProcessPoolExecutor(max_workers=a.jobs) as pool:
        for row in pool.map(_run, range(a.draws), [a.master_seed] * a.draws,
                            [str(a.out)] * a.draws):
            rows.append(row)
            print(f"draw {row['index']}: " + ("error " + row["error"] if "error" in row else
                  json.dumps({s: {m: v["four_contact"] for m, v in e.items() if m != "observer"}
                              for s, e in row["suites"].items()})), file=sys.stderr)
    summary = _summary(rows)
    (a.out / "runs.json").write_text(json.dumps(rows, indent=1, default=float))
    (a.out / "summary.json").write_text(json.dumps(summary, indent=1))
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
