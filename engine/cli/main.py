"""Command-line interface: ``vitaplace run|validate|config|simulate|train|evaluate|report|difficulty|plugins|sweep|aggregate|import|view|video``.

User errors (bad scenario, missing file, unknown plugin, corrupt dataset, diverged
training) print one line ``vitaplace: error: ...`` and exit with code 2, no traceback.
A sweep in which some seeds failed writes the summary of the others and exits with 1.

Every command takes ``-v`` (debug messages too) or ``-q`` (warnings and errors only, no
progress bars), before or after its name; messages go to stderr (and ``OUT/log.txt``, which
keeps every info line), so ``run --json`` (and ``difficulty --json``) leaves only the JSON on stdout. With
shtab installed (``pip install "vitaplace[completion]"``), ``vitaplace --print-completion
bash`` prints a shell completion script.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import TextIO

from vitaplace.engine import __version__
from vitaplace.engine.base.cpus import limit_blas_threads, usable_cpus
from vitaplace.engine.base.errors import UserError
from vitaplace.engine.outputs.outdir import claimed, writable_dir

EXIT_USER_ERROR = 2
EXIT_SEEDS_FAILED = 1


def _verbosity() -> argparse.ArgumentParser:
    """-v/-q, for the main parser and every command (no default here: see `main`)."""
    parent = argparse.ArgumentParser(add_help=False)
    group = parent.add_mutually_exclusive_group()
    group.add_argument("-v", "--verbose", dest="log_level", action="store_const", const=logging.DEBUG,
                       default=argparse.SUPPRESS, help="debug messages too")
    group.add_argument("-q", "--quiet", dest="log_level", action="store_const", const=logging.WARNING,
                       default=argparse.SUPPRESS,
                       help="only warnings and errors on stderr, no progress bars (OUT/log.txt keeps everything)")
    return parent


def _add_scenario_args(parser: argparse.ArgumentParser, out: bool = True, out_name: str = "<scenario name>") -> None:
    parser.add_argument("scenario", help="scenario YAML file, or the name of a built-in one (e.g. quickstart)")
    parser.add_argument(
        "--set", dest="overrides", action="append", default=[], metavar="KEY.PATH=VALUE",
        help="override a scenario value, e.g. --set methods.0.params.epochs=2; KEY.PATH+=VALUE appends to a "
        "list, e.g. --set 'methods+={name: L2, plugin: mupnet}' (VALUE is YAML; repeatable)",
    )
    if out:
        parser.add_argument("--out", type=Path, help=f"output directory (default: runs/{out_name})")
        parser.add_argument(
            "--force", action="append", nargs="?", const="all", default=[], metavar="STAGE",
            help="redo a stage even if cached: simulate, fit, transform, evaluate, report (repeatable); "
            "--force alone (or --force all) redoes every stage the command runs",
        )
        parser.add_argument("--no-progress", action="store_true", help="no progress bars")


def build_parser() -> argparse.ArgumentParser:
    common = _verbosity()
    parser = argparse.ArgumentParser(
        prog="vitaplace",
        description="Visuo-tactile place recognition with a simulated whiskered robot (MuPNet vs ViTa-SLAM).",
        parents=[common],
    )
    parser.add_argument("--version", action="version", version=f"vitaplace {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    stages = {
        "run": "run the whole pipeline and write the report",
        "simulate": "record the scenario's datasets (HDF5), or one foraging run of an environment file",
        "train": "simulate, then fit every method on the training run",
        "evaluate": "everything up to the evaluation: results.json and results.csv",
        "report": "everything, then (re)write the report (cached stages reused); `report OUT`: rebuild it from OUT",
    }
    for name, help_text in stages.items():
        p = sub.add_parser(name, help=help_text, description=help_text, parents=[common])
        _add_scenario_args(p)
        if name in ("run", "evaluate", "report"):
            p.add_argument("--json", action="store_true", help="print the results rows as JSON on stdout")
        if name == "simulate":
            p.add_argument("--samples", type=int, help="environment file only: number of samples (default 200)")
            p.add_argument("--seed", type=int, default=0, help="environment file only: run seed")
    p = sub.add_parser(
        "difficulty", parents=[common],
        help="whether touch can matter: the touch measures and H-V/H-T complementarity of every evaluation against "
        "its gates, with the hand-crafted methods only (the scenario's methods are not run)",
    )
    _add_scenario_args(p, out_name="<scenario name>-difficulty")
    p.add_argument("--json", action="store_true",
                   help="print one JSON row per evaluation and direction on stdout (difficulty, complementarity, gates)")
    p = sub.add_parser(
        "validate", parents=[common],
        help="check a scenario or an environment file (or a shipped one by name) without running anything",
    )
    _add_scenario_args(p, out=False)
    p = sub.add_parser("config", parents=[common],
                       help="print the resolved scenario as YAML: what run would use (extends merged, --set applied)")
    _add_scenario_args(p, out=False)
    sub.add_parser("plugins", parents=[common], help="list the feature-extractor plugins and any that failed to load")
    p = sub.add_parser(
        "import", parents=[common], help="convert a MultiPredNet/WhiskEye MATLAB folder into a run file (HDF5)"
    )
    p.add_argument("source", type=Path, help="folder with images.mat, theta.mat, xy.mat and poses.mat")
    p.add_argument("--out", type=Path, required=True, help="the run file to write (e.g. runs/real/query.h5)")
    p.add_argument("--name", help="name of the run (default: the folder's name)")
    p.add_argument("--image-range", choices=("0-1", "0-255"),
                   help="range of float images when the data cannot tell (0-1 saturates values above 1)")
    p.add_argument("--pose-layout", choices=("Nx3", "3xN"), help="layout of a 3 x 3 pose array (three samples)")
    p.add_argument("--tactile-model", choices=("physical", "penetration"), default="physical",
                   help="what the whiskers' xy are: physical (sprung whiskers, MultiPredNet's Gazebo WhiskEye; the "
                   "default) or penetration (docs/SIMULATION.md); recorded in the run file")
    _add_sweep_command(sub, common)
    p = sub.add_parser(
        "aggregate", parents=[common],
        help="summarise run folders of one scenario made by independent jobs (e.g. a SLURM array)",
    )
    p.add_argument("folders", nargs="+", type=Path, metavar="DIR", help="run folders (vitaplace run --set seed=N --out DIR)")
    p.add_argument("--out", type=Path, help="where the summary goes (default: the folders' common parent)")
    p = sub.add_parser(
        "sensitivity", parents=[common],
        help="rescore a run's or sweep's saved evaluations for other revisit and heading tolerances",
    )
    p.add_argument("folder", type=Path, metavar="DIR", help="a finished run folder or a sweep folder (seed-*/)")
    p.add_argument("--tau", type=float, nargs="+", help="revisit tolerances in metres (default 0.2 0.3 0.5)")
    p.add_argument("--heading-tolerance", type=float, metavar="DEG",
                   help="heading tolerance scored beside position only (default 30)")
    p.add_argument("--sequence-length", type=int, metavar="L",
                   help="score sequences of L queries (SeqSLAM, docs/DESIGN.md) instead of what the run scored")
    p.add_argument("--out", type=Path, help="where sensitivity.csv/.md/.json go (default: DIR)")
    _add_viewing_commands(sub, common)
    _add_completion(parser)
    return parser


def _add_sweep_command(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """`vitaplace sweep`: seeds, and where they run (local pool, Ray, SLURM) with what each reserves."""
    p = sub.add_parser("sweep", parents=[common], help="run a scenario over several seeds (local process pool, Ray or SLURM)")
    _add_scenario_args(p)
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="scenario seeds to run")
    p.add_argument(
        "--grid", action="append", default=[], metavar="KEY.PATH=V1,V2,...",
        help="run every seed at each value of a --set path, e.g. --grid methods.0.params.epochs=30,90,270 (values "
        "parsed as YAML; several --grid options form their product; one folder OUT/<path end>=<value> per grid point)",
    )
    p.add_argument("--replace", action="store_true",
                   help="replace a summary in --out that covers seeds or grid points this sweep lacks (refused without it)")
    p.add_argument(
        "--workers", type=int, default=None,
        help="local worker processes (default: the CPUs this process may use / --cpus-per-job)",
    )
    p.add_argument(
        "--ray", metavar="ADDRESS",
        help="run on Ray: 'auto' joins a running cluster or starts a local one; else the cluster's address",
    )
    p.add_argument(
        "--slurm", nargs="?", const="slurm", choices=("slurm", "local"), metavar="local",
        help="run as one SLURM array job through submitit (logs in OUT/slurm); '--slurm local' runs its tasks "
        "on this machine through submitit's local executor",
    )
    p.add_argument("--cpus-per-job", type=float, default=1, metavar="N", help="CPUs each seed reserves (default 1)")
    p.add_argument(
        "--gpus-per-job", type=float, default=0, metavar="N",
        help="GPUs each seed reserves on Ray or SLURM (default 0); > 0 also selects the GPU backend of methods that "
        "have one",
    )
    slurm = p.add_argument_group("SLURM (with --slurm)")
    slurm.add_argument("--partition", help="the partition to submit to (default: the cluster's)")
    slurm.add_argument("--time", help="time limit of one seed's task, as sbatch reads it (e.g. 04:00:00 or 90)")
    slurm.add_argument("--mem", help="memory of one seed's task, as sbatch reads it (e.g. 16G)")
    slurm.add_argument(
        "--max-parallel", type=int, metavar="N",
        help="at most N of the array's tasks at once (sbatch's --array=...%%N; default: every seed at once)",
    )
    slurm.add_argument(
        "--sbatch", action="append", default=[], metavar="NAME=VALUE",
        help="any other sbatch option, e.g. --sbatch account=myproject --sbatch qos=high (NAME alone: a flag; "
        "repeatable)",
    )


def _add_viewing_commands(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``view ENV`` (MuJoCo's interactive viewer) and ``video RUN.h5`` (an animation of a run)."""
    p = sub.add_parser("view", parents=[common],
                       help="open MuJoCo's interactive viewer on an environment with the robot (needs a display)")
    p.add_argument("environment", help="environment YAML file, or the name of a shipped one (e.g. e1)")
    p = sub.add_parser("video", parents=[common],
                       help="animate a recorded run: camera frames, top view with trajectory, whisker contacts")
    p.add_argument("run", type=Path, help="run file (HDF5), e.g. from `vitaplace simulate ENV.yaml`")
    p.add_argument("--out", type=Path, help="the video to write, .gif (always) or .mp4 (needs ffmpeg); default RUN.gif")
    p.add_argument("--fps", type=float, default=5.0, help="frames per second, 0.1 to 50 (default 5; one sample per 0.5 s whisk cycle)")
    p.add_argument("--step", type=int, help="draw every STEP-th sample (default 1, or larger to keep to 300 frames)")


def _view(args: argparse.Namespace) -> int:
    from vitaplace.engine.sim.viewer import view

    view(args.environment)
    return 0


def _video(args: argparse.Namespace) -> int:
    from vitaplace.engine.data.dataset import open_run
    from vitaplace.engine.sim.video import write_video

    if args.step is not None and args.step < 1:
        raise UserError(f"--step {args.step}: expected a whole number >= 1")
    path, frames = write_video(open_run(args.run), args.out or args.run.with_suffix(".gif"), args.fps, args.step)
    print(f"wrote {frames} frames to {path}")
    return 0


def _add_completion(parser: argparse.ArgumentParser) -> None:
    """``--print-completion bash|zsh|tcsh`` where the optional shtab is installed."""
    try:
        import shtab
    except ImportError:
        return
    shtab.add_argument_to(parser, ["--print-completion"], help="print a shell completion script")


class _StderrHandler(logging.StreamHandler):
    """A handler that writes to ``sys.stderr`` as it is when a message comes (redirections work)."""

    @property  # type: ignore[override]
    def stream(self) -> TextIO:
        return sys.stderr

    @stream.setter
    def stream(self, value: TextIO) -> None:
        pass


def _console_logging(level: int) -> None:
    """Messages of ``level`` and above on stderr; the logger passes info lines at least (for log.txt)."""
    logger = logging.getLogger("vitaplace")
    logger.setLevel(min(level, logging.INFO))
    for handler in logger.handlers:
        handler.close()
    logger.handlers.clear()
    console = _StderrHandler()
    console.setLevel(level)
    console.setFormatter(logging.Formatter("%(message)s"))
    logger.addHandler(console)


def _setup_logging(out: Path) -> None:
    """Also log to ``out/log.txt`` (every message the logger passes, whatever -q says)."""
    file_handler = logging.FileHandler(out / "log.txt")
    file_handler.setFormatter(logging.Formatter("%(asctime)s %(message)s"))
    logging.getLogger("vitaplace").addHandler(file_handler)


def _forced(force: list[str], until: str, command: str) -> list[str]:
    """The stages ``--force`` names, ``all`` being every stage up to ``until``; a stage the
    command does not reach is refused (it would be ignored)."""
    from vitaplace.engine.pipeline.runner import STAGES

    reached = STAGES[: STAGES.index(until) + 1]
    late = [s for s in force if s in STAGES and s not in reached]
    if late:
        raise UserError(
            f"--force {' '.join(late)}: `vitaplace {command}` stops after the {until} stage and would not run it; "
            "use a command that gets there (e.g. `vitaplace run`)"
        )
    return list(dict.fromkeys(stage for s in force for stage in (reached if s == "all" else (s,))))


def _run_stages(args: argparse.Namespace, until: str) -> int:
    from vitaplace.engine.config.loading import load_scenario
    from vitaplace.engine.pipeline.orchestrate import run_stages
    from vitaplace.engine.pipeline.runner import Pipeline

    args.force = _forced(args.force, until, args.command)
    scenario, resolved = load_scenario(args.scenario, args.overrides)
    log = logging.getLogger("vitaplace")
    with claimed(args.out or Path("runs") / scenario.name, _setup_logging) as out:
        rows = run_stages(Pipeline(scenario, resolved, out, force=args.force, progress=not args.no_progress), until)
    for row in rows:
        log.info(
            "%-6s %-12s %-20s max F1 %.2f %%  AUC %.3f",
            row["environment"], row["method"], row["direction"], 100 * row["max_f1"], row["auc"],
        )
    if until in ("report", "evaluate"):
        log.info("results in %s", out / ("report.md" if until == "report" else "results.csv"))
    if getattr(args, "json", False):
        print(json.dumps(rows, indent=2))
    return 0


def _difficulty(args: argparse.Namespace) -> int:
    """`vitaplace difficulty SCENARIO`: the stages up to the evaluation with the hand-crafted
    family (`vitaplace.engine.cli.difficulty`), then each evaluation's measures against its
    gates; exit 0 whether or not the gates are met."""
    from vitaplace.engine.cli.difficulty import difficulty_rows, family_overrides, table
    from vitaplace.engine.config.loading import load_scenario
    from vitaplace.engine.outputs.outdir import COMPLEMENTARITY
    from vitaplace.engine.pipeline.orchestrate import run_stages
    from vitaplace.engine.pipeline.runner import Pipeline

    args.force = _forced(args.force, "evaluate", args.command)
    scenario, resolved = load_scenario(args.scenario, [*args.overrides, *family_overrides()])
    with claimed(args.out or Path("runs") / f"{scenario.name}-difficulty", _setup_logging) as out:
        rows = run_stages(Pipeline(scenario, resolved, out, force=args.force, progress=not args.no_progress), "evaluate")
        measured = difficulty_rows(scenario, rows, json.loads((out / COMPLEMENTARITY).read_text()))
    print(json.dumps(measured, indent=2) if args.json else table(measured))
    return 0


def _report_folder(args: argparse.Namespace) -> int:
    """`vitaplace report OUT`: report.md and the figures rebuilt from a run's output folder alone."""
    from vitaplace.engine.report.report import rebuild_report

    given = [flag for flag, value in (("--set", args.overrides), ("--force", args.force), ("--out", args.out),
                                      ("--json", args.json)) if value]
    if given:
        raise UserError(f"{' '.join(given)}: apply to a scenario; `vitaplace report {args.scenario}` rebuilds the report "
                        "of that output folder from its files as they are")
    with claimed(Path(args.scenario)) as out:
        path = rebuild_report(out)
    print(f"wrote {path} and its figures")
    return 0


def _simulate_environment(args: argparse.Namespace) -> int:
    """`vitaplace simulate ENV.yaml`: one foraging run of an environment file."""
    from vitaplace.engine.data.dataset import write_run
    from vitaplace.engine.sim.environment import load_environment
    from vitaplace.engine.sim.simulate import run_spec, simulate_run

    if args.force or args.overrides:
        raise UserError(
            f"{'--force' if args.force else '--set'} applies to scenarios; `vitaplace simulate ENV.yaml` always "
            "records its run anew (its settings: --samples, --seed)"
        )
    environment = load_environment(args.scenario)
    spec = run_spec(kind="foraging", n_samples=args.samples or 200)
    run = simulate_run(environment, spec, seed=args.seed, progress=not args.no_progress, name=Path(args.scenario).stem)
    out = writable_dir(args.out or Path("runs") / "datasets")
    path = write_run(out / f"{Path(args.scenario).stem}-foraging-seed{args.seed}.h5", run)
    print(f"wrote {len(run)} samples to {path}")
    return 0


def own_top_level_keys() -> tuple[set[str], set[str]]:
    """The top-level keys only environment files have and those only scenario files have
    (old names included), from the two schemas."""
    from vitaplace.engine.config.scenario import RENAMED_KEYS, Scenario
    from vitaplace.engine.sim.environment import EnvironmentSpec

    environment, scenario = set(EnvironmentSpec.model_fields), set(Scenario.model_fields) | set(RENAMED_KEYS)
    return environment - scenario, scenario - environment


def _is_environment_file(name: str) -> bool:
    """Whether ``name`` is an environment file (or a shipped environment's name), not a scenario."""
    from vitaplace.engine.base.configfile import ConfigError, load_yaml, read_yaml
    from vitaplace.engine.base.shipped import ENVIRONMENTS_DIR, SCENARIOS_DIR, shipped_file

    path = Path(name)
    if not path.exists() and not path.suffix and shipped_file(name, (ENVIRONMENTS_DIR,)):
        return shipped_file(name, (SCENARIOS_DIR,)) is None
    if path.suffix not in (".yaml", ".yml") or not path.is_file():
        return False
    try:
        data = load_yaml(path)
    except ConfigError:
        try:
            data = read_yaml(path)  # its own keys; load_environment then says what is wrong with 'extends'
        except ConfigError:
            return False  # reported by the scenario loader
    environment_keys, scenario_keys = own_top_level_keys()
    return bool(environment_keys & data.keys()) and not scenario_keys & data.keys()


def _plugins() -> int:
    from vitaplace.engine.extension.registry import discover

    registry = discover()
    rows = []
    for name in registry.names():
        doc = (registry.get(name).__doc__ or "").strip().splitlines()
        rows.append((name, registry.sources[name], doc[0] if doc else ""))
    rows += [("(failed)", source, why) for source, why in registry.failed.items()]
    width_name = max((len(r[0]) for r in rows), default=0)
    width_source = max((len(r[1]) for r in rows), default=0)
    for name, source, text in rows:
        print(f"{name:{width_name}}  {source:{width_source}}  {text}")
    return 0


def _validate_environment(args: argparse.Namespace) -> int:
    """`vitaplace validate ENV.yaml`: load and check an environment file, one line."""
    from vitaplace.engine.sim.environment import load_environment

    if args.overrides:
        raise UserError("--set applies to scenarios, not to environment files")
    env = load_environment(args.scenario)
    print(
        f"{args.scenario}: valid environment '{env.name}': arena {2 * env.arena.half_x:g} x {2 * env.arena.half_y:g} m, "
        f"{len(env.landmarks)} landmark(s), route of {len(env.route)} waypoint(s)"
    )
    return 0


def _validate(args: argparse.Namespace) -> int:
    from vitaplace.engine.config.loading import load_scenario

    if _is_environment_file(args.scenario):
        return _validate_environment(args)
    from vitaplace.engine.sim.plausibility import LONG_SECONDS, duration, estimated_seconds

    scenario, _ = load_scenario(args.scenario, args.overrides)
    runs = [scenario.train.run] + [e.run for e in scenario.evaluations for _ in ("query", "reference")]
    seconds = sum(estimated_seconds(run, scenario.robot) for run in runs if run is not None)
    long = f"; simulating its runs takes about {duration(seconds)} on one core (estimate)" if seconds > LONG_SECONDS else ""
    print(
        f"{args.scenario}: valid scenario '{scenario.name}': {len(scenario.evaluations)} evaluation environment(s), "
        f"methods {', '.join(m.name for m in scenario.methods)}"
        + "".join(f", fusion {f.name} ({f.vision} + w {f.touch})" for f in scenario.fusions) + long
    )
    return 0


def _config(args: argparse.Namespace) -> int:
    """`vitaplace config SCENARIO [--set ...]`: the resolved scenario, as a run writes it into
    ``scenario.resolved.yaml``."""
    import yaml

    from vitaplace.engine.config.loading import load_scenario

    _, resolved = load_scenario(args.scenario, args.overrides)
    print(yaml.safe_dump(resolved, sort_keys=False), end="")
    return 0


def _import(args: argparse.Namespace) -> int:
    """`vitaplace import SRC --out RUN.h5`: a MultiPredNet-layout folder as a run file."""
    from vitaplace.engine.data.dataset import DatasetError, write_run
    from vitaplace.engine.data.matimport import import_mat

    if args.out.is_dir():
        raise DatasetError(f"--out {args.out}: is a folder; expected the run file to write (e.g. {args.out / 'run.h5'})")
    run = import_mat(args.source, name=args.name, image_range=args.image_range, pose_layout=args.pose_layout,
                     tactile_model=args.tactile_model)
    try:
        path = write_run(args.out, run)
    except OSError as exc:
        raise DatasetError(f"--out {args.out}: cannot write ({exc.strerror or exc})") from None
    print(f"imported {len(run)} samples from {args.source} into {path}")
    return 0


def _sweep(args: argparse.Namespace) -> int:
    from vitaplace.engine.cli.slurm import check_queue_clear, settings_from_args
    from vitaplace.engine.study.summary import cell
    from vitaplace.engine.cli.sweep import check_placement, load_sweep_scenario, run_sweep
    from vitaplace.engine.study.grid import grid_points, load_points, parse_axes

    if args.cpus_per_job <= 0 or args.gpus_per_job < 0:
        raise UserError("--cpus-per-job must be > 0 and --gpus-per-job >= 0")
    if args.workers is not None and args.workers < 1:
        raise UserError(f"--workers {args.workers}: expected a number of worker processes, at least 1")
    slurm = settings_from_args(args)
    check_placement(args.workers, args.ray, slurm, args.gpus_per_job)
    axes = parse_axes(args.grid, args.overrides)
    scenario, resolved = load_sweep_scenario(args.scenario, args.overrides, args.gpus_per_job)
    grid = load_points(grid_points(axes), lambda point: load_sweep_scenario(
        args.scenario, [*args.overrides, *point], args.gpus_per_job)) if axes else []
    log = logging.getLogger("vitaplace")
    out = Path(args.out or Path("runs") / f"{scenario.name}-sweep")
    if slurm is not None and slurm.cluster == "slurm":
        check_queue_clear(out / "slurm")  # before claiming OUT cleans files its tasks may be writing
    with claimed(out, _setup_logging) as out:
        outcome = run_sweep(
            scenario, resolved, args.seeds, out, args.workers, args.ray, not args.no_progress,
            _forced(args.force, "report", "sweep"),
            args.cpus_per_job, args.gpus_per_job, slurm, grid, args.replace,
        )
    for row in outcome.summary:
        if row["metric"] == "max_f1":
            log.info("%s%-6s %-12s %-20s max F1 %s", f"{row['point']} " if grid else "", row["environment"],
                     row["method"], row["direction"], cell(row))
    table, runs = out / ("grid.md" if grid else "sweep.md"), len(args.seeds) * max(1, len(grid))
    if outcome.failed:
        log.error("%d of %d seeds failed, missing from the summary: %s; summary of the others in %s",
                  len(outcome.failed), runs, " ".join(map(str, sorted(outcome.failed))), table)
        return EXIT_SEEDS_FAILED
    log.info("summary of %d seeds in %s", runs, table)
    return 0


def _aggregate(args: argparse.Namespace) -> int:
    from vitaplace.engine.study.aggregate import aggregate_runs

    out, record = aggregate_runs(args.folders, args.out)
    print(f"summary of {len(record['seeds'])} seeds in {out / 'sweep.md'}")
    return 0


def _sensitivity(args: argparse.Namespace) -> int:
    from vitaplace.engine.study.sensitivity import write_sensitivity

    grid = {"taus": args.tau, "heading_tolerance_deg": args.heading_tolerance, "sequence_length": args.sequence_length}
    out, record = write_sensitivity(args.folder, args.out, **{k: v for k, v in grid.items() if v is not None})
    print(f"sensitivity of {len(record['seeds'])} seed(s) in {out / 'sensitivity.md'}")
    return EXIT_SEEDS_FAILED if record["failed"] else 0


def main(argv: list[str] | None = None) -> int:
    """The command line; a Ctrl-C at any moment (even while parsing or importing) ends it with one line."""
    try:
        return _main(argv)
    except KeyboardInterrupt:
        print("vitaplace: interrupted; finished stages are cached, run again to resume", file=sys.stderr)
        return 130


def _main(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)
    level = getattr(args, "log_level", logging.INFO)
    _console_logging(level)
    if level > logging.INFO and hasattr(args, "no_progress"):
        args.no_progress = True
    logging.getLogger("vitaplace").debug("vitaplace %s, Python %s", __version__, sys.version.split()[0])
    try:
        limit_blas_threads(usable_cpus())
        if args.command == "plugins":
            return _plugins()
        if args.command == "validate":
            return _validate(args)
        if args.command == "config":
            return _config(args)
        if args.command == "sweep":
            return _sweep(args)
        if args.command == "aggregate":
            return _aggregate(args)
        if args.command == "sensitivity":
            return _sensitivity(args)
        if args.command == "import":
            return _import(args)
        if args.command in ("view", "video"):
            return _view(args) if args.command == "view" else _video(args)
        if args.command == "difficulty":
            return _difficulty(args)
        if args.command == "report" and Path(args.scenario).is_dir():
            return _report_folder(args)
        if args.command == "simulate" and _is_environment_file(args.scenario):
            return _simulate_environment(args)
        until = {"simulate": "simulate", "train": "fit", "evaluate": "evaluate"}.get(args.command, "report")
        return _run_stages(args, until)
    except UserError as exc:
        print(f"vitaplace: error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR


if __name__ == "__main__":
    sys.exit(main())
