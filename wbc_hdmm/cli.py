"""The ``wbc`` command: list, run, compare, estimate, bench, demo, machine.

Every error becomes one line on stderr (``wbc: error: ...``) and exit code 2; Ctrl-C during a
run writes the partial log and metrics (``"partial": true``) and exits with 130.
"""

from __future__ import annotations

import pickle
import sys
import zipfile
from pathlib import Path

import click

from wbc_hdmm.output import OutputError, prepare_out_dir
from wbc_hdmm.report import acceptance_lines, comparison_table, metrics_lines, sweep_lines

__all__ = ["cli", "main"]

CONTROLLERS = ("tracking", "mpc-quasi-static", "mpc-full")
BENCHES = ("simulator", "estimator", "controller", "observer", "qp")  # `benchmarks.BENCHES`
EXTRA_BENCHES = ("ticks",)  # `benchmarks.EXTRA`: only when named
FAMILY_NAMES = ("random", "heavy-pick-downhill", "fast-swing-steep", "standing-on-rough")
EXIT_ERROR = 2
EXIT_INTERRUPTED = 130

# Errors that are the user's input or files, not bugs: one line and exit code 2.
_USER_ERRORS = (ValueError, KeyError, OSError, EOFError, zipfile.BadZipFile,
                pickle.UnpicklingError, OutputError)


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("wbc-hdmm")
    except PackageNotFoundError:
        return "unknown (not installed)"


class _ScenarioHelp(click.Command):
    """A command whose help ends with the scenarios (imported only when help is shown)."""

    def format_epilog(self, ctx, formatter) -> None:
        from scenarios.registry import describe

        for kind, scenarios in describe().items():
            with formatter.section(f"{kind.capitalize()} scenarios"):
                formatter.write_dl(list(scenarios.items()))
        super().format_epilog(ctx, formatter)


def _out_option(default: str):
    return click.option("--out", default=default, show_default=True,
                        type=click.Path(file_okay=True, dir_okay=True, path_type=Path),
                        help="Output folder; refused if it is a file, not writable, or not "
                             "empty (see --force).")


_force_option = click.option("--force", is_flag=True,
                             help="Write into a non-empty output folder (same-named files "
                                  "are replaced).")
_progress_option = click.option("--no-progress", is_flag=True,
                                help="No progress bars (they go to stderr).")
_sensors_option = click.option(
    "--sensors", type=click.Choice(("realistic", "ideal", "oracle")), default="realistic",
    show_default=True, help="What the controller sees (closed loop): the machine's sensors "
    "through the observer with datasheet errors (realistic) or without (ideal), or the "
    "simulator's exact state (oracle; the payload is then told).")


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(_version(), "--version", prog_name="wbc",
                      message="%(prog)s %(version)s")
def cli() -> None:
    """Stability-aware whole-body MPC for a heavy hydraulic mobile manipulator.

    Start with 'wbc list', then 'wbc run SCENARIO' or 'wbc compare SCENARIO'.
    """


@cli.command("list")
def list_cmd() -> None:
    """List the scenarios and controllers, one line each."""
    from scenarios.registry import DEFAULT_CONTROLLER, describe
    from wbc.controllers.registry import CONTROLLER_NAMES

    for kind, scenarios in describe().items():
        click.echo(f"{kind} scenarios:")
        for name, text in scenarios.items():
            click.echo(f"  {name:20s} {text}")
    descriptions = {
        "tracking": "whole-body QP that tracks the operator's motion, no force constraint",
        "mpc-quasi-static": "MPC with the quasi-static normal-force estimator",
        "mpc-full": "MPC with the full-dynamics normal-force estimator",
    }
    click.echo(f"controllers (closed-loop scenarios; default {DEFAULT_CONTROLLER}):")
    for name in CONTROLLER_NAMES:
        click.echo(f"  {name:20s} {descriptions.get(name, '')}")
    from models.sensor_suites import SUITES
    from scenarios.families import SUMMARIES

    click.echo("scenario families (wbc sweep --family NAME):")
    for name, text in SUMMARIES.items():
        click.echo(f"  {name:20s} {text}")
    suites = {"oracle": "the simulator's exact state, payload told at a pick (comparison only)",
              "ideal": "the machine's sensors without their errors, through the observer",
              "realistic": "the sensors with their datasheet errors (default; docs/sensors.md)"}
    click.echo("sensor suites (wbc run / sweep --sensors NAME):")
    for name in SUITES:
        click.echo(f"  {name:20s} {suites.get(name, '')}")


def _scenario_argument(scenario, scenario_file):
    """The scenario name, or the validated scenario of ``scenario_file`` (exactly one)."""
    if (scenario is None) == (scenario_file is None):
        raise ValueError("give a SCENARIO name or --scenario-file FILE (exactly one); "
                         "`wbc list` shows the names")
    if scenario_file is None:
        return scenario
    from scenarios.scenario_file import load_scenario_file

    return load_scenario_file(scenario_file)


def _run_target(scenario, scenario_file, family, draw_index, master_seed, seed):
    """``(scenario, terrain seed)`` of `wbc run`: a name, a file, or a family's draw."""
    if (family is None) != (draw_index is None):
        raise ValueError("--family and --draw go together (a family's draw K)")
    if family is None:
        return _scenario_argument(scenario, scenario_file), 0 if seed is None else seed
    if scenario is not None or scenario_file is not None:
        raise ValueError("give a SCENARIO name, --scenario-file FILE or --family with --draw "
                         "(exactly one)")
    if seed is not None:
        raise ValueError("a family's draw has its own terrain seed; drop --seed")
    from scenarios.families import draw

    d = draw(family, draw_index, master_seed)
    return d.scenario, d.terrain_seed


@cli.command("run", cls=_ScenarioHelp)
@click.argument("scenario", required=False)
@click.option("--scenario-file", type=click.Path(dir_okay=False), default=None,
              help="A closed-loop scenario in TOML (format: scenarios/scenario_file.py; "
                   "example: examples/heavy-swing.toml) instead of SCENARIO.")
@click.option("--controller", type=click.Choice(CONTROLLERS), default=None,
              help="Closed-loop controller  [default: mpc-full; open-loop scenarios take "
                   "none]")
@click.option("--duration", type=float, default=None,
              help="Simulated time [s], more than the 1 s settling  [default: the "
                   "scenario's]")
@click.option("--family", type=click.Choice(FAMILY_NAMES), default=None,
              help="Run draw --draw of this scenario family (as `wbc sweep` runs it, with "
                   "the draw's terrain seed) instead of SCENARIO.")
@click.option("--draw", "draw_index", type=click.IntRange(min=0), default=None,
              help="Index of the family's draw.")
@click.option("--master-seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Master seed of the family's draws.")
@click.option("--seed", type=int, default=None,
              help="Terrain seed, an integer >= 0  [default: 0; a family draw has its own]")
@click.option("--threshold", type=float, default=None,
              help="Normal-force threshold [N] (closed loop)  [default: 10 % of the static "
                   "wheel load]")
@_sensors_option
@click.option("--noise", type=click.Choice(("none", "default")), default="none",
              show_default=True, help="Measurement-noise preset on the oracle state.")
@click.option("--delay", type=int, default=0, show_default=True,
              help="Measurement delay [control periods of 10 ms] (closed loop).")
@_out_option("out/run")
@_force_option
@_progress_option
def run_cmd(scenario, scenario_file, controller, duration, family, draw_index, master_seed,
            seed, threshold, sensors, noise, delay, out, force, no_progress) -> int:
    """Run one scenario (a name, --scenario-file or a family's --draw); write its log.

    The log (log.npz) and metrics.json go to --out; a family's draw runs as `wbc sweep` runs
    it, with the draw's own terrain seed.
    """
    scenario, seed = _run_target(scenario, scenario_file, family, draw_index, master_seed,
                                 seed)
    out = prepare_out_dir(out, force)
    from scenarios import registry

    metrics = registry.run(scenario, out_dir=out, controller=controller, duration=duration,
                           seed=seed, progress=not no_progress, noise=noise,
                           delay_periods=delay, threshold_n=threshold, sensors=sensors)
    label = getattr(scenario, "name", scenario)
    title = f"{label} ({metrics.get('controller', 'open-loop')})"
    click.echo("\n".join(metrics_lines(title, metrics)))
    click.echo(f"   wrote {out / 'log.npz'}, {out / 'metrics.json'}")
    return 0


@cli.command("sweep")
@click.option("--family", type=click.Choice(FAMILY_NAMES),
              default="random", show_default=True, help="Scenario family to draw from.")
@click.option("--draws", type=click.IntRange(min=1), default=20, show_default=True, help="Draws.")
@click.option("--first", type=click.IntRange(min=0), default=0, show_default=True,
              help="Index of the first draw.")
@click.option("--controllers", default="tracking,mpc-full", show_default=True, help="Comma-"
              "separated controllers.")
@click.option("--master-seed", type=click.IntRange(min=0), default=0, show_default=True,
              help="Master seed of the draws (the acceptance runs use one not tuned on).")
@click.option("-j", "--jobs", type=click.IntRange(min=1), default=2, show_default=True,
              help="Local worker processes.")
@click.option("--ray", "ray_address", default=None,
              help="Run on Ray: 'local' starts Ray here, else a cluster address.")
@_sensors_option
@_out_option("out/sweep")
@_force_option
@_progress_option
def sweep_cmd(family, draws, first, controllers, master_seed, jobs, ray_address, sensors, out,
              force, no_progress) -> int:
    """Run many random draws of a scenario family; write sweep.jsonl and summary.json."""
    names = [c.strip() for c in controllers.split(",") if c.strip()]
    unknown = [c for c in names if c not in CONTROLLERS]
    if not names or unknown:
        what = f"unknown {unknown}" if unknown else "none given"
        raise ValueError(f"--controllers: {what}; valid: {', '.join(CONTROLLERS)} "
                         f"(comma-separated)")
    out = prepare_out_dir(out, force)
    from scenarios.progress import Progress
    from scenarios.sweep import run_sweep

    with Progress(draws * len(names), f"sweep {family}", enabled=None if not no_progress
                  else False, unit="runs") as bar:
        summary = run_sweep(family, draws, names, out, master_seed=master_seed, jobs=jobs,
                            ray_address=ray_address, first=first, options={"sensors": sensors},
                            progress=lambda done, total: bar.update(done))
    rerun = (f"wbc run --family {family} --draw {{index}} --master-seed {master_seed} "
             f"--controller {{controller}} --sensors {sensors} --out out/draw-{{index}}")
    click.echo("\n".join(sweep_lines(summary, names, rerun)))
    click.echo(f"   wrote {out / 'sweep.jsonl'}, {out / 'summary.json'}")
    return 0


@cli.command("compare", cls=_ScenarioHelp)
@click.argument("scenario", required=False)
@click.option("--scenario-file", type=click.Path(dir_okay=False), default=None,
              help="A closed-loop scenario in TOML instead of SCENARIO.")
@click.option("--duration", type=float, default=None,
              help="Simulated time [s]  [default: the scenario's]")
@click.option("--seed", type=int, default=0, show_default=True,
              help="Terrain seed, an integer >= 0.")
@_out_option("out/compare")
@_force_option
@_progress_option
def compare_cmd(scenario, scenario_file, duration, seed, out, force, no_progress) -> int:
    """Run the three controllers on one closed-loop scenario (same terrain and seed).

    SCENARIO defaults to swing-out. Prints a table; writes each controller's log and metrics,
    forces.png and comparison.json to --out.
    """
    from scenarios import registry

    if scenario is None and scenario_file is None:
        scenario = "swing-out"
    scenario = _scenario_argument(scenario, scenario_file)
    if isinstance(scenario, str) and not registry.is_closed_loop(scenario):
        raise ValueError(f"'{scenario}' is not a closed-loop scenario; valid: "
                         f"{', '.join(registry.describe()['closed-loop'])}")
    from scenarios.run_args import check_seed

    check_seed(seed)
    out = prepare_out_dir(out, force)
    from scenarios.comparison import run_comparison

    result = run_comparison(scenario, out, duration=duration, seed=seed,
                            progress=not no_progress)
    click.echo(f"== {result['scenario']}: the three controllers, seed {seed}")
    click.echo("\n".join(comparison_table(result["metrics"])))
    click.echo("acceptance:")
    click.echo("\n".join(acceptance_lines(result["acceptance"])))
    click.echo(f"wrote {out / 'comparison.json'}, {result['plot']}")
    return 0


@cli.command("estimate")
@click.argument("log", type=click.Path(path_type=Path))
@click.option("--out", type=click.Path(path_type=Path), default=None,
              help="Output folder  [default: the log's folder]")
@click.option("--no-plots", is_flag=True, help="Skip the figures.")
@click.option("--sensors", type=click.Choice(("oracle", "ideal", "realistic")), multiple=True,
              help="Sensor suite to score (repeat for several)  [default: every suite the "
                   "log has]")
@_progress_option
def estimate_cmd(log, out, no_plots, sensors, no_progress) -> int:
    """Evaluate every estimator method on a scenario log (log.npz or its folder).

    The methods' main table is on the simulator's measured state (the oracle); each sensor
    suite's observer state is scored beside it (``sensor_suites`` in estimation.json).
    """
    import json

    from estimators.evaluate import evaluate_log

    if out is not None:
        prepare_out_dir(out, force=True)
    log_file = log / "log.npz" if log.is_dir() else log
    if log_file.is_file() and not zipfile.is_zipfile(log_file):
        raise ValueError(f"'{log_file}' is not a readable scenario log (a log.npz written by "
                         f"wbc run): not an npz archive, or truncated")
    try:
        from models.log import load_log
        from scenarios.progress import Progress

        load_log(log)  # a bad file is one line before the progress bar starts
        with Progress(1.0, "estimate", enabled=False if no_progress else None,
                      unit="") as bar:
            report = evaluate_log(log, out, plots=not no_plots, progress=bar.update,
                                  suites=sensors or None)
    except (zipfile.BadZipFile, EOFError, pickle.UnpicklingError) as exc:
        raise ValueError(f"'{log}' is not a readable scenario log (a log.npz written by "
                         f"wbc run): {exc}") from exc
    except KeyError as exc:
        raise ValueError(f"'{log}' is not a scenario log: it lacks the key {exc}") from exc
    click.echo(json.dumps(report.get("summary", report), indent=2))
    return 0


@cli.command("bench")
@click.option("--out", type=click.Path(path_type=Path), default=Path("out/bench"),
              show_default=True, help="Output folder.")
@click.option("--only", type=click.Choice(BENCHES + EXTRA_BENCHES), default=None,
              help="One benchmark  [default: all but the long ones: ticks]")
def bench_cmd(out, only) -> int:
    """Benchmarks of the simulator, the estimator, the controllers and the QP solvers.

    ``--only ticks``: the control ticks of 20 closed-loop runs (about 4 min), not in the
    default set.
    """
    prepare_out_dir(out, force=True)
    import benchmarks

    benchmarks.main(["--out", str(out)] + (["--only", only] if only else []))
    return 0


@cli.command("demo")
@_out_option("out")
@_force_option
@_progress_option
def demo_cmd(out, force, no_progress) -> int:
    """The main job: the paper's open-loop runs with the estimators, then the controllers."""
    out = prepare_out_dir(out, force)
    from wbc_hdmm.demo import demo

    return demo(out, progress=not no_progress)


@cli.command("machine")
@click.option("--write-mjcf", type=click.Path(path_type=Path), default=None,
              help="Folder to write the MJCF files to.")
@click.option("--doc", type=click.Path(path_type=Path), default=None,
              help="Markdown file to write the figures to.")
@click.option("--load-chart", "chart_file", type=click.Path(path_type=Path), default=None,
              help="Print the load chart (rated payload by reach and slew) and plot it to "
                   "this PNG file.")
@click.option("--slope", type=float, default=0.0, show_default=True,
              help="Side slope of the load chart [deg], the crane's side downhill.")
def machine_cmd(write_mjcf, doc, chart_file, slope) -> int:
    """Print the machine's figures and their sources (or its load chart)."""
    from models import build_reference_machine

    machine = build_reference_machine()
    if chart_file is not None:
        from wbc_hdmm.load_chart_plot import print_and_plot

        click.echo(print_and_plot(machine, chart_file, slope))
        return 0
    if doc:
        from models.report import machine_markdown

        doc.parent.mkdir(parents=True, exist_ok=True)
        doc.write_text(machine_markdown(machine))
        click.echo(f"wrote {doc}")
    if write_mjcf:
        from models.mujoco import write_mjcf as write

        paths = write(machine, write_mjcf)
        click.echo("wrote " + " ".join(map(str, paths.values())))
    click.echo(f"total mass {machine.total_mass:.1f} kg, {len(machine.bodies)} bodies, "
               f"{len(machine.loops)} closed chains")
    for item, value, source in machine.sources:
        click.echo(f"- {item}: {value}  [{source}]")
    return 0


@cli.command("render")
@click.argument("run_dir", type=click.Path(path_type=Path))
@click.option("--out", "out_file", type=click.Path(path_type=Path), default=None,
              help="The mp4 to write  [default: RUN_DIR/run.mp4]")
@click.option("--fps", type=int, default=30, show_default=True, help="Frames per second.")
@click.option("--width", type=int, default=640, show_default=True, help="3-D view [px].")
@click.option("--height", type=int, default=360, show_default=True, help="3-D view [px].")
@click.option("--force", is_flag=True, help="Overwrite an existing file.")
@_progress_option
def render_cmd(run_dir, out_file, fps, width, height, force, no_progress) -> int:
    """Render a run (a folder written by wbc run) to an mp4.

    A chase camera, force arrows coloured by their margin to the threshold, the forces
    plotted beside.
    """
    from models.log import load_log
    from scenarios.progress import Progress
    from wbc_hdmm.render import check_out, render_run

    out_file = out_file or Path(run_dir) / "run.mp4"
    if out_file.exists() and not force:
        raise OutputError(f"--out '{out_file}' exists; use --force to overwrite it")
    check_out(out_file)  # refused in one line before the progress bar starts
    load_log(run_dir)  # so is a missing or unreadable log
    with Progress(1.0, "render", enabled=None if not no_progress else False,
                  unit="") as bar:
        path = render_run(run_dir, out_file, fps=fps, width=width, height=height,
                          progress=bar.update)
    click.echo(f"wrote {path}")
    return 0


@cli.command("export")
@click.argument("run_dir", type=click.Path(path_type=Path))
@click.option("--format", "fmt", type=click.Choice(("csv", "parquet")), default="csv",
              show_default=True, help="Table format.")
@click.option("--out", type=click.Path(path_type=Path), default=None,
              help="Output folder  [default: RUN_DIR]")
def export_cmd(run_dir, fmt, out) -> int:
    """Write a run's log as a table (samples.csv or .parquet) with units.json and meta.json."""
    from wbc_hdmm.export import export_run

    if out is not None:
        out = prepare_out_dir(out, force=True)
    for path in export_run(run_dir, fmt, out):
        click.echo(f"wrote {path}")
    return 0


@cli.command("view")
@click.argument("run_dir", type=click.Path(path_type=Path))
def view_cmd(run_dir) -> int:
    """Replay a run in MuJoCo's viewer (needs a display; headless, use wbc render)."""
    from wbc_hdmm.view import view_run

    view_run(run_dir)
    return 0


def _project_errors() -> tuple[type[Exception], ...]:
    """The packages' error bases (typed errors with messages for the user)."""
    from estimators.errors import EstimatorError
    from models.errors import ModelError
    from scenarios.errors import SimulatorError
    from wbc.errors import WbcError

    return ModelError, EstimatorError, WbcError, SimulatorError


def _error(message: str) -> int:
    text = " ".join(str(message).split())  # one line
    click.echo(f"wbc: error: {text}", err=True)
    return EXIT_ERROR


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``wbc`` console command; returns the exit code."""
    from scenarios.errors import RunInterrupted

    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv:  # the overview, not a usage error
        argv = ["--help"]
    try:
        rv = cli.main(args=argv, prog_name="wbc", standalone_mode=False)
    except click.exceptions.Exit as exc:
        return exc.exit_code
    except click.UsageError as exc:
        hint = f" (see wbc {exc.ctx.info_name} --help)" if exc.ctx is not None \
            and exc.ctx.parent is not None else " (see wbc --help)"
        return _error(exc.format_message() + hint)
    except click.Abort as exc:
        cause = exc.__cause__ or exc.__context__
        if isinstance(cause, EOFError):  # click turns EOFError into Abort too
            return _error(f"unexpected end of a file or of the input ({cause})")
        if isinstance(cause, RunInterrupted):
            where = f"; partial log and metrics in {cause.out_dir}" if cause.out_dir else ""
            click.echo(f"wbc: interrupted ({cause}){where}", err=True)
        else:
            click.echo("wbc: interrupted; nothing saved", err=True)
        return EXIT_INTERRUPTED
    except click.ClickException as exc:
        return _error(exc.format_message())
    except Exception as exc:
        if not isinstance(exc, _USER_ERRORS + _project_errors()):
            raise
        if isinstance(exc, KeyError):
            return _error(f"missing key {exc}")
        if isinstance(exc, OSError) and exc.filename is not None:
            return _error(f"{exc.strerror or exc}: '{exc.filename}'")
        return _error(str(exc) or type(exc).__name__)
    return int(rv or 0)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
