"""The ``hoc`` command line: a thin typer layer over ``hoc_cli.commands``.

Standard output carries only CSV (``-o -``) or JSON (``--json``); progress, tables and
errors go to standard error. Exit codes: see ``hoc_cli.commands.common``.

The annotations here are evaluated when the module loads (no ``from __future__ import annotations``):
typer reads them at every run, and strings would be evaluated one by one (start-up time).
"""
from pathlib import Path
from typing import Annotated, Optional

import typer

from hoc_cli import __version__
from hoc_cli.commands.common import refuse_irregular, run_guarded
from hoc_cli.commands.option_values import install as install_option_values
from hoc_cli.commands.usage import OneLineGroup

install_option_values()  # plain option values converted without pydantic (start-up time)

app = typer.Typer(
    name="hoc",
    cls=OneLineGroup,  # a usage error is one `hoc: error:` line, exit 2
    help=(
        "Covariant optimal-control trajectory planner for jointed robot arms.\n\n"
        "Example: hoc plan configs/lbr7_reach.yaml -o reach.mcap -o reach.csv"
    ),
    no_args_is_help=True,
    add_completion=True,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)

OutputOpt = Annotated[
    Optional[list[str]],
    typer.Option("-o", "--output", metavar="FILE", help="Output file (.mcap or .csv; repeatable); '-' writes CSV to stdout; "
                 "'none' writes no file (e.g. with --json). Default: <task stem>.mcap and <task stem>.csv in the current directory. "
                 "An output that is an input is refused."),
]
SimOutputOpt = Annotated[
    Optional[list[str]],
    typer.Option("-o", "--output", metavar="FILE", help="Output file (.mcap or .csv; repeatable); '-' writes CSV to stdout; "
                 "'none' writes no file (e.g. with --json). Default, for a task YAML and an MCAP source alike: "
                 "<source stem>-sim.mcap and <source stem>-sim.csv "
                 "in the current directory (never the plan's own files; an output that is an input is refused)."),
]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print one JSON summary object on stdout.")]
QuietOpt = Annotated[bool, typer.Option("-q", "--quiet", help="Nothing on stderr but errors (no warnings either).")]
ProgressOpt = Annotated[bool, typer.Option("--progress", help="Show progress and the summary table on stderr even when it is not a terminal.")]
DebugOpt = Annotated[bool, typer.Option("--debug", help="Show Python tracebacks for errors.")]
ElementsOpt = Annotated[Optional[int], typer.Option("-N", "--elements", help="Override the task's number of elements N (>= 1).")]
OrderOpt = Annotated[Optional[str], typer.Option("--order", help="Override the element order: quintic | cubic.")]
DurationOpt = Annotated[Optional[float], typer.Option("-T", "--duration", help="Override the duration T in seconds (> 0).")]


MCAP_PLAN = "a plan's MCAP file written by hoc plan"


def _inputs_checked(inputs: list, body):
    """``body`` run after every input file that exists is found to be a regular file (``refuse_irregular``;
    a missing one is the command's to report, in its own order of checks).
    """
    def run() -> int:
        refuse_irregular(inputs, missing_ok=True)
        return body()
    return run


def _version(value: bool) -> None:
    if value:
        typer.echo(f"hoc {__version__}")
        raise typer.Exit(0)


@app.callback()
def main(
    version: Annotated[bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")] = False,
) -> None:
    """Covariant optimal-control trajectory planner for jointed robot arms."""


@app.command()
def plan(
    task: Annotated[Path, typer.Argument(metavar="TASK.yaml", help="Task YAML file (see the README's task-file reference).")],
    output: OutputOpt = None,
    json_: JsonOpt = False,
    quiet: QuietOpt = False,
    progress: ProgressOpt = False,
    elements: ElementsOpt = None,
    order: OrderOpt = None,
    duration: DurationOpt = None,
    tol: Annotated[Optional[float], typer.Option("--tol", help="Override solver.tol (> 0).")] = None,
    max_iter: Annotated[Optional[int], typer.Option("--max-iter", help="Override solver.max_iter (>= 1).")] = None,
    method: Annotated[Optional[str], typer.Option("--method", help="Override solver.method: pr-cg | newton.")] = None,
    cost: Annotated[Optional[str], typer.Option("--cost", help="Override the cost: covariant | torque.")] = None,
    init: Annotated[Optional[Path], typer.Option("--init", help="Warm start from an earlier plan's MCAP.")] = None,
    limits: Annotated[Optional[str], typer.Option(
        "--limits", help="enforce (default: the plan respects every joint limit) | report (the unconstrained "
        "optimum; violations are only reported). Overrides limits.mode.")] = None,
    collision: Annotated[Optional[str], typer.Option(
        "--collision", help="enforce (plan clear of obstacles and of the robot itself, certified between samples; "
        "the default with a collision section) | check (plan without the constraint, then certify and report "
        "collisions) | off. Overrides collision.mode.")] = None,
    check_gradient: Annotated[bool, typer.Option(
        "--check-gradient", help="Only check the cost gradient at the initial guess against central differences; "
        "exit 1 if the max relative error exceeds 1e-6.")] = False,
    starts: Annotated[Optional[int], typer.Option("--starts", min=1, help="Multi-start: solve from the minimum-jerk guess and K-1 seeded "
                                                  "perturbations of it; keep the lowest-J converged plan. Overrides solver.starts.")] = None,
    seed: Annotated[Optional[int], typer.Option("--seed", min=0, help="Seed of the multi-start perturbations (same seed, same starts). "
                                                "Overrides solver.seed.")] = None,
    debug: DebugOpt = False,
) -> None:
    """Solve the optimal-control task and write q(t), u(t).

    Example: hoc plan configs/lbr7_reach.yaml -o reach.mcap --json | jq .cost
    """
    from hoc_cli.commands import plan as cmd

    code = run_guarded(_inputs_checked([(init, "--init", MCAP_PLAN)],
        lambda: cmd.run(
            task, outputs=output, as_json=json_, quiet=quiet, progress=progress,
            overrides=dict(N=elements, order=order, T=duration, tol=tol, max_iter=max_iter, method=method, cost=cost,
                           limits=limits, collision=collision),
            init=init, gradient_check=check_gradient, starts=starts, seed=seed,
        )),
        debug=debug, quiet=quiet,
    )
    raise typer.Exit(code)


@app.command()
def batch(
    spec: Annotated[list[Path], typer.Argument(metavar="SPEC.yaml...", help="A batch spec (base task + sweep, or a list of task files), "
                                                                      "or task files / globs.")],
    output: Annotated[Optional[Path], typer.Option("-o", "--output", metavar="DIR", help="Results directory (results.parquet, results.csv, plans/). "
                                                                       "Default: <spec stem>_batch.")] = None,
    workers: Annotated[Optional[int], typer.Option("--workers", min=1, help="Worker processes of the embedded local cluster "
                                                                         "(default: one per core; at most 4 per core).")] = None,
    scheduler: Annotated[Optional[str], typer.Option("--scheduler", metavar="ADDRESS", help="Use a running Dask scheduler (e.g. tcp://host:8786; "
                                                                  "default: $DASK_SCHEDULER_ADDRESS, else a local cluster).")] = None,
    connect_timeout: Annotated[Optional[float], typer.Option("--connect-timeout", metavar="SECONDS", help="How long to wait for the "
                                                             "--scheduler to answer as a Dask scheduler (default 10).")] = None,
    resume: Annotated[bool, typer.Option("--resume", help="Keep the rows already in DIR/results.parquet and solve only the plans not in it.")] = False,
    json_: JsonOpt = False,
    quiet: QuietOpt = False,
    progress: Annotated[bool, typer.Option("--progress", help="Show the progress bar on stderr even when it is not a terminal.")] = False,
    debug: DebugOpt = False,
) -> None:
    """Solve many plans on Dask (a local cluster by default) and tabulate them in DIR/results.parquet and .csv.

    Example: hoc batch sweep.yaml -o sweep_results --workers 2
    """
    from hoc_cli.commands import batch as cmd

    code = run_guarded(_inputs_checked(
        [(p, None, "a batch spec or task YAML file") for p in spec],
        lambda: cmd.run(spec, out_dir=output, workers=workers, scheduler=scheduler, resume=resume, as_json=json_,
                        quiet=quiet, progress=progress, connect_timeout=connect_timeout)),
        debug=debug, quiet=quiet,
    )
    raise typer.Exit(code)


@app.command()
def simulate(
    source: Annotated[Path, typer.Argument(metavar="SOURCE", help="Task YAML (with optional torque:) or a plan's MCAP file.")],
    output: SimOutputOpt = None,
    json_: JsonOpt = False,
    quiet: QuietOpt = False,
    progress: ProgressOpt = False,
    elements: ElementsOpt = None,
    order: OrderOpt = None,
    duration: DurationOpt = None,
    integrator: Annotated[Optional[str], typer.Option(
        "--integrator", help="hermite (the paper's collocation, default) | rk (scipy DOP853 reference).")] = None,
    method: Annotated[Optional[str], typer.Option(
        "--method", help="Deprecated spelling of --integrator (kept for one release; a note on stderr).")] = None,
    torque: Annotated[Optional[Path], typer.Option("--torque", help="Torque history from a plan's CSV or MCAP (interpolated in time).")] = None,
    check: Annotated[Optional[float], typer.Option("--check", help="Exit 1 when the final state misses x1 by more than this.")] = None,
    tol: Annotated[Optional[float], typer.Option(
        "--tol", help="Integrator tolerance (> 0): hermite, the Newton step per element (default 1e-13); "
        "rk, DOP853's rtol = atol (default 1e-12). The task's solver.tol is the planner's and is not used.")] = None,
    max_iter: Annotated[Optional[int], typer.Option(
        "--max-iter", help="hermite only: Newton iterations per element before it is subdivided (>= 1, default 25).")] = None,
    debug: DebugOpt = False,
) -> None:
    """Integrate the motion forward from x0 under a torque history.

    Example: hoc plan task.yaml -o plan.mcap && hoc simulate plan.mcap --check 1e-8
    """
    from hoc_cli.commands import simulate as cmd

    code = run_guarded(_inputs_checked(
        [(source, None, "a task YAML or " + MCAP_PLAN), (torque, "--torque", "a plan's CSV or MCAP file")],
        lambda: cmd.run(
            source, outputs=output, as_json=json_, quiet=quiet, progress=progress,
            overrides=dict(N=elements, order=order, T=duration), integrator=integrator, method=method,
            torque=torque, check=check, tol=tol, max_iter=max_iter,
        )),
        debug=debug, quiet=quiet,
    )
    raise typer.Exit(code)


@app.command()
def catch(
    scenario: Annotated[Path, typer.Argument(metavar="SCENARIO.yaml", help="Catch scenario: task, throw, observe, cycle (README).")],
    json_: JsonOpt = False,
    seed: Annotated[Optional[int], typer.Option("--seed", help="Override observe.seed (the observations' noise).")] = None,
    noise: Annotated[Optional[float], typer.Option("--noise", help="Override observe.noise, σ in m (>= 0).")] = None,
    output: Annotated[Optional[Path], typer.Option("-o", "--output", metavar="FILE.mcap", help="Write the run to MCAP.")] = None,
    quiet: QuietOpt = False,
    debug: DebugOpt = False,
) -> None:
    """Simulate catching a thrown ball in real time: noisy observations, the estimate, a replan every cycle.

    Example: hoc catch configs/catch_throw.yaml --json | jq .caught
    """
    from hoc_cli.commands import catch as cmd

    code = run_guarded(lambda: cmd.run(scenario, as_json=json_, seed=seed, noise=noise, output=output, quiet=quiet),
                       debug=debug, quiet=quiet)
    raise typer.Exit(code)


@app.command()
def inspect(
    robot: Annotated[Path, typer.Argument(metavar="ROBOT.urdf", help="URDF file.")],
    json_: JsonOpt = False,
    collision: Annotated[bool, typer.Option("--collision", help="List each link's collision primitives and their "
                                            "volume against the geometry's (docs/collision.md).")] = False,
    debug: DebugOpt = False,
) -> None:
    """Print the parsed kinematic tree: joints, bodies, total mass, degrees of freedom.

    Example: hoc inspect robots/lbr7.urdf --json
    """
    from hoc_cli.commands import inspect as cmd

    raise typer.Exit(run_guarded(_inputs_checked([(robot, None, "a URDF file")],
                                                 lambda: cmd.run(robot, as_json=json_, collision=collision)),
                                 debug=debug))


@app.command()
def verify(
    json_: JsonOpt = False,
    quiet: QuietOpt = False,
    only: Annotated[Optional[list[str]], typer.Option("--only", help="Run only these checks (repeatable).")] = None,
    debug: DebugOpt = False,
) -> None:
    """Reproduce the paper's numerical claims and print measured beside expected; exit 1 on a miss.

    Example: hoc verify --json
    """
    from hoc_cli.commands import verify as cmd

    raise typer.Exit(run_guarded(lambda: cmd.run(as_json=json_, quiet=quiet, only=only), debug=debug, quiet=quiet))


@app.command()
def plot(
    files: Annotated[list[Path], typer.Argument(metavar="FILE...", help="Plan or simulation CSV or MCAP files (several: overlaid).")],
    output: Annotated[Path, typer.Option("-o", "--output", help="PNG (or PDF/SVG) file to write.")] = Path("plot.png"),
    robot: Annotated[Optional[Path], typer.Option(
        "--robot", help="URDF whose limits to draw (a CSV carries none; default for an MCAP: its own URDF).")] = None,
    normalized: Annotated[bool, typer.Option(
        "--normalized", help="Every joint divided by its limits in three panels (±1 = the limits).")] = False,
    debug: DebugOpt = False,
) -> None:
    """Plot q, q̇ and u of each joint against t, with its limits (needs matplotlib: pip install 'hoc[plot]').

    Example: hoc plot covariant.mcap torque.mcap -o compare.png
    """
    from hoc_cli.commands import plot as cmd

    inputs = [(f, None, "a plan's CSV or MCAP file") for f in files] + [(robot, "--robot", "a URDF file")]
    raise typer.Exit(run_guarded(_inputs_checked(
        inputs, lambda: cmd.run(files, output, robot=robot, normalized=normalized)), debug=debug))


@app.command()
def new(
    robot: Annotated[Path, typer.Argument(metavar="ROBOT.urdf", help="URDF file of the robot.")],
    output: Annotated[Optional[str], typer.Option(
        "-o", "--output", metavar="FILE", help="Task file to write (.yaml); '-' writes it to stdout. "
        "Default: <robot stem>.yaml in the current directory.")] = None,
    force: Annotated[bool, typer.Option("--force", help="Replace an existing output file.")] = False,
    quiet: QuietOpt = False,
    debug: DebugOpt = False,
) -> None:
    """Write a commented task template for a robot that plans as written (then edit x1, T and N).

    Example: hoc new robots/lbr7.urdf -o reach.yaml && hoc plan reach.yaml
    """
    from hoc_cli.commands import new as cmd

    raise typer.Exit(run_guarded(_inputs_checked([(robot, None, "a URDF file")],
                                                 lambda: cmd.run(robot, output, force=force, quiet=quiet)),
                                 debug=debug, quiet=quiet))


@app.command()
def examples(
    name: Annotated[Optional[str], typer.Argument(metavar="[NAME]", help="Example to copy (omit to list them).")] = None,
    directory: Annotated[Path, typer.Option("--dir", help="Folder to copy the example and its robot into.")] = Path("."),
    force: Annotated[bool, typer.Option("--force", help="Replace existing files.")] = False,
    quiet: QuietOpt = False,
    debug: DebugOpt = False,
) -> None:
    """List the example tasks shipped with hoc, or copy one (with its robot's URDF) into a folder.

    Example: hoc examples lbr7_reach && hoc plan lbr7_reach.yaml
    """
    from hoc_cli.commands import examples as cmd

    raise typer.Exit(run_guarded(lambda: cmd.run(name, directory, force=force, quiet=quiet), debug=debug, quiet=quiet))
