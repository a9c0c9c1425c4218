"""Command line: ``wbc run``, ``wbc estimate``, ``wbc bench``, ``wbc demo``, ``wbc machine``."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _print_metrics(name: str, metrics: dict) -> None:
    keys = ("sim_seconds", "wall_seconds", "real_time_factor", "max_closure_violation_m",
            "min_normal_force_N", "contact_loss_fraction", "tipped", "task_error_final",
            "time_below_threshold_s", "fallbacks")
    print(f"== {name}")
    for k in keys:
        if k in metrics:
            v = metrics[k]
            if isinstance(v, dict):
                v = ", ".join(f"{kk} {vv:.4g}" if isinstance(vv, float) else f"{kk} {vv}"
                              for kk, vv in v.items())
            elif isinstance(v, float):
                v = f"{v:.4g}"
            print(f"   {k:26s} {v}")


def _cmd_run(args) -> int:
    from scenarios import registry

    metrics = registry.run(args.scenario, out_dir=Path(args.out), controller=args.controller,
                           duration=args.duration, seed=args.seed,
                           progress=not args.no_progress)
    _print_metrics(f"{args.scenario} ({args.controller or 'open-loop'})", metrics)
    print(f"   wrote {Path(args.out) / 'metrics.json'}")
    return 0


def _cmd_estimate(args) -> int:
    from estimators.evaluate import evaluate_log

    report = evaluate_log(Path(args.log), Path(args.out) if args.out else None,
                          plots=not args.no_plots)
    print(json.dumps(report.get("summary", report), indent=2))
    return 0


def _cmd_bench(args) -> int:
    import benchmarks

    benchmarks.main(["--out", args.out] + (["--only", args.only] if args.only else []))
    return 0


def _cmd_demo(args) -> int:
    from wbc_hdmm.demo import demo

    return demo(Path(args.out), progress=not args.no_progress)


def _cmd_machine(args) -> int:
    from models import build_reference_machine

    machine = build_reference_machine()
    if args.doc:
        from models.report import machine_markdown

        Path(args.doc).parent.mkdir(parents=True, exist_ok=True)
        Path(args.doc).write_text(machine_markdown(machine))
        print("wrote", args.doc)
    if args.write_mjcf:
        from models.mujoco import write_mjcf

        paths = write_mjcf(machine, Path(args.write_mjcf))
        print("wrote", *map(str, paths.values()))
    print(f"total mass {machine.total_mass:.1f} kg, {len(machine.bodies)} bodies, "
          f"{len(machine.loops)} closed chains")
    for item, value, source in machine.sources:
        print(f"- {item}: {value}  [{source}]")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``wbc`` command."""
    p = argparse.ArgumentParser(prog="wbc", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("run", help="run a scenario (open loop or closed loop)")
    r.add_argument("scenario", help="scenario name; `wbc run list` lists them")
    r.add_argument("--out", default="out/run", help="output folder (log.npz, metrics.json)")
    r.add_argument("--controller", default=None,
                   help="closed-loop controller: tracking, mpc-quasi-static, mpc-full")
    r.add_argument("--duration", type=float, default=None, help="override duration [s]")
    r.add_argument("--seed", type=int, default=0, help="terrain seed")
    r.add_argument("--no-progress", action="store_true")
    r.set_defaults(func=_cmd_run)

    e = sub.add_parser("estimate", help="evaluate every estimator method on a scenario log")
    e.add_argument("log", help="log.npz or the folder holding it")
    e.add_argument("--out", default=None, help="output folder (default: the log's folder)")
    e.add_argument("--no-plots", action="store_true")
    e.set_defaults(func=_cmd_estimate)

    b = sub.add_parser("bench", help="benchmarks (simulator, estimator, controller)")
    b.add_argument("--out", default="out/bench")
    b.add_argument("--only", default=None, help="simulator, estimator or controller")
    b.set_defaults(func=_cmd_bench)

    d = sub.add_parser("demo", help="the main job: scenarios with a summary")
    d.add_argument("--out", default="out")
    d.add_argument("--no-progress", action="store_true")
    d.set_defaults(func=_cmd_demo)

    m = sub.add_parser("machine", help="print the machine's figures and sources")
    m.add_argument("--write-mjcf", default=None, help="folder to write the MJCF files to")
    m.add_argument("--doc", default=None, help="markdown file to write the figures to")
    m.set_defaults(func=_cmd_machine)
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``wbc`` console command."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, KeyError, FileNotFoundError) as exc:
        print(f"wbc: error: {exc}", file=sys.stderr)
        return 2
