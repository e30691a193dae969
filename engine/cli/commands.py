"""What each ``vitaplace`` command does: one handler per command, taking the parsed arguments and
returning the exit code; `vitaplace.engine.cli.main.build_parser` binds each to its command with
``set_defaults(handler=...)``. A user error raises `UserError` (`main` prints its one line).
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path
from typing import TYPE_CHECKING

from vitaplace.engine.base.errors import UserError
from vitaplace.engine.outputs.completion import holder, refuse_other
from vitaplace.engine.outputs.outdir import OutputDirError, claimed, refuse_foreign, writable_dir

if TYPE_CHECKING:
    from vitaplace.engine.sim.controllers import RunSpec

EXIT_SEEDS_FAILED = 1


def _setup_logging(out: Path) -> None:
    """Also log to ``out/log.txt`` (every message the logger passes, whatever -q says)."""
    file_handler = logging.FileHandler(out / "log.txt")
    file_handler.setFormatter(logging.Formatter("%(asctime)s %(message)s"))
    logging.getLogger("vitaplace").addHandler(file_handler)


def _forced(force: list[str], until: str, command: str) -> list[str]:
    """The stages ``--force`` names, ``all`` being every stage up to ``until``; a stage the
    command does not reach is refused (it would be ignored)."""
    from vitaplace.engine.pipeline.keys import STAGES

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
    from vitaplace.engine.pipeline.store import Store

    args.force = _forced(args.force, until, args.command)
    scenario, resolved = load_scenario(args.scenario, args.overrides)
    log = logging.getLogger("vitaplace")
    with claimed(args.out or Path("runs") / scenario.name, _setup_logging) as out:
        rows = run_stages(scenario, resolved, Store(out, force=args.force, progress=not args.no_progress), until)
    for row in rows:
        log.info(
            "%-6s %-12s %-20s max F1 %.2f %%  AUC %.3f",
            row.environment, row.method, row.direction, 100 * row.max_f1, row.auc,
        )
    if rows:  # the report when the folder has one (`run_stages` carries on to it)
        log.info("results in %s", out / ("report.md" if (out / "report.md").is_file() else "results.csv"))
    if getattr(args, "json", False):
        print(json.dumps([row.dump() for row in rows], indent=2))
    return 0


def run_command(args: argparse.Namespace) -> int:
    """`vitaplace run SCENARIO`: every stage, the report last."""
    return _run_stages(args, "report")


def simulate_command(args: argparse.Namespace) -> int:
    """`vitaplace simulate`: a scenario's datasets, or one foraging run of an environment file."""
    if _is_environment_file(args.scenario):
        return _simulate_environment(args)
    if args.replace:
        raise UserError("--replace applies to `vitaplace simulate ENV.yaml`'s run file; a scenario's runs are "
                        "cached by their settings (`--force simulate` records them anew)")
    given = [option for option, value in (("--samples", args.samples), ("--seed", args.seed)) if value is not None]
    if given:
        raise UserError(f"{' and '.join(given)} apply to `vitaplace simulate ENV.yaml`; a scenario's runs take "
                        "theirs from the scenario (e.g. --set train.run.n_samples=N --set seed=S)")
    return _run_stages(args, "simulate")


def train_command(args: argparse.Namespace) -> int:
    """`vitaplace train SCENARIO`: the stages up to and including the fit."""
    return _run_stages(args, "fit")


def evaluate_command(args: argparse.Namespace) -> int:
    """`vitaplace evaluate SCENARIO`: the stages up to and including the evaluation."""
    return _run_stages(args, "evaluate")


def report_command(args: argparse.Namespace) -> int:
    """`vitaplace report SCENARIO` runs every stage; `vitaplace report OUT` rebuilds OUT's report."""
    if Path(args.scenario).is_dir():
        return _report_folder(args)
    return _run_stages(args, "report")


def difficulty_command(args: argparse.Namespace) -> int:
    """`vitaplace difficulty SCENARIO`: the stages up to the evaluation with the hand-crafted
    family (`vitaplace.engine.cli.difficulty`) into ``OUT/difficulty``, reusing the stages
    cached in ``OUT`` (a run's or a sweep's folder), then each evaluation's measures against
    its gates; exit 0 whether or not the gates are met."""
    from vitaplace.engine.cli.difficulty import difficulty_rows, family_overrides, table
    from vitaplace.engine.config.loading import load_scenario
    from vitaplace.engine.outputs.outdir import COMPLEMENTARITY, cache_dir, difficulty_dir
    from vitaplace.engine.pipeline.orchestrate import run_stages
    from vitaplace.engine.pipeline.store import Store

    args.force = _forced(args.force, "evaluate", args.command)
    scenario, resolved = load_scenario(args.scenario, [*args.overrides, *family_overrides()])
    with claimed(args.out or Path("runs") / scenario.name) as host:  # held: its cache is written
        if holder(host) == "difficulty":
            raise OutputDirError(f"--out {host}: holds the output of `vitaplace difficulty`; give the folder whose "
                                 f"stage cache it reuses ({host.parent}), it writes {difficulty_dir(host.parent)}")
        with claimed(difficulty_dir(host), _setup_logging) as out:
            store = Store(out, force=args.force, progress=not args.no_progress, cache=cache_dir(host))
            rows = run_stages(scenario, resolved, store, "evaluate", command="difficulty")
            measured = difficulty_rows(scenario, rows, json.loads((out / COMPLEMENTARITY).read_text()))
    print(json.dumps(measured, indent=2) if args.json else table(measured))
    return 0


def export_command(args: argparse.Namespace) -> int:
    """`vitaplace export SCENARIO --out DIR`: its evaluations for VPR tools and/or its runs as a package."""
    from vitaplace.engine.cli.export import export_scenario

    written = export_scenario(args.scenario, args.overrides, args.out, args.format, args.runs, not args.no_progress,
                              _setup_logging)
    print("\n".join(f"wrote {path}" for path in written))
    return 0


def _report_folder(args: argparse.Namespace) -> int:
    """`vitaplace report OUT`: report.md and the figures rebuilt from a run's output folder alone."""
    from vitaplace.engine.report.report import rebuild_report

    given = [flag for flag, value in (("--set", args.overrides), ("--force", args.force), ("--out", args.out),
                                      ("--json", args.json)) if value]
    if given:
        raise UserError(f"{' '.join(given)}: apply to a scenario; `vitaplace report {args.scenario}` rebuilds "
                        "the report of that output folder from its files as they are")
    with claimed(Path(args.scenario), option="OUT") as out:
        path, settings = rebuild_report(out)
    drawn = {"all": " and its figures", "summary": " and its summary figures", "none": ""}[settings.figures]
    print(f"wrote {path}{drawn}")
    return 0


def _simulate_environment(args: argparse.Namespace) -> int:
    """`vitaplace simulate ENV.yaml`: one foraging run of an environment file."""
    from vitaplace.engine.data.dataset import write_run
    from vitaplace.engine.sim.environment import load_environment
    from vitaplace.engine.sim.simulate import simulate_run

    if args.force or args.overrides:
        raise UserError(
            f"{'--force' if args.force else '--set'} applies to scenarios; `vitaplace simulate ENV.yaml` always "
            "records its run anew (its settings: --samples, --seed)"
        )
    environment = load_environment(args.scenario)
    args.seed = 0 if args.seed is None else args.seed
    spec = _foraging_run(args)
    name = Path(args.scenario).stem
    out = Path(args.out or Path("runs") / "datasets")
    refuse_other(out, "`vitaplace simulate ENV.yaml`")  # a run's or a sweep's folder is not its own
    target = writable_dir(out) / f"{name}-foraging-seed{args.seed}.h5"
    if target.is_dir():
        raise UserError(f"{target}: is a folder; expected the run file to write there (move it, or another --out)")
    if target.exists() and not args.replace:
        raise OutputDirError(f"--out {out}: already holds {target.name}, a run a scenario's `dataset:` may read; "
                             "--replace records it anew, or give another --out")
    run = simulate_run(environment, spec, seed=args.seed, progress=not args.no_progress, name=name)
    path = write_run(target, run)
    print(f"wrote {len(run)} samples to {path}")
    return 0


def _foraging_run(args: argparse.Namespace) -> RunSpec:
    """The foraging run of `vitaplace simulate ENV.yaml` (--samples, default 200) once it and
    --seed are known to be usable: a UserError naming the option otherwise."""
    from vitaplace.engine.config.memory import physical_memory, run_memory_problem
    from vitaplace.engine.sim.controllers import run_spec
    from vitaplace.engine.sim.robot import RobotSpec

    samples = 200 if args.samples is None else args.samples
    if samples < 1:
        raise UserError(f"--samples {samples}: expected a number of samples, at least 1")
    from vitaplace.engine.study.grid import seed_range

    low, high = seed_range()
    if not low <= args.seed < high:
        raise UserError(f"--seed {args.seed}: expected a whole number >= {low} and < {high}, as a scenario's seed")
    spec = run_spec(kind="foraging", n_samples=samples)
    problem = run_memory_problem(spec, RobotSpec(), physical_memory())
    if problem:
        raise UserError(f"--samples {samples}: {problem}")
    return spec


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


def plugins_command(args: argparse.Namespace) -> int:
    """`vitaplace plugins`: each extractor plugin, where it comes from and its summary; then those that failed."""
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
        f"{args.scenario}: valid environment '{env.name}': "
        f"arena {2 * env.arena.half_x:g} x {2 * env.arena.half_y:g} m, "
        f"{len(env.landmarks)} landmark(s), route of {len(env.route)} waypoint(s)"
    )
    return 0


def validate_command(args: argparse.Namespace) -> int:
    """`vitaplace validate FILE`: check a scenario or an environment file, one line."""
    from vitaplace.engine.config.loading import load_scenario

    if _is_environment_file(args.scenario):
        return _validate_environment(args)
    from vitaplace.engine.sim.plausibility import LONG_SECONDS, duration, estimated_seconds

    scenario, _ = load_scenario(args.scenario, args.overrides)
    runs = [scenario.train.run] + [e.run for e in scenario.evaluations for _ in ("query", "reference")]
    seconds = sum(estimated_seconds(run, scenario.robot) for run in runs if run is not None)
    long = (f"; simulating its runs takes about {duration(seconds)} on one core (estimate)"
            if seconds > LONG_SECONDS else "")
    print(
        f"{args.scenario}: valid scenario '{scenario.name}': {len(scenario.evaluations)} evaluation environment(s), "
        f"methods {', '.join(m.name for m in scenario.methods)}"
        + "".join(f", fusion {f.name} ({f.vision} + w {f.touch})" for f in scenario.fusions) + long
    )
    return 0


def config_command(args: argparse.Namespace) -> int:
    """`vitaplace config SCENARIO [--set ...] [--resolved]`: the resolved scenario, as a run writes it
    into ``scenario.resolved.yaml``; with ``--resolved``, every default filled in, each method's
    parameters as its plugin receives them (`plan.method_settings`)."""
    import yaml

    from vitaplace.engine.config.loading import load_scenario

    scenario, resolved = load_scenario(args.scenario, args.overrides)
    if args.resolved:
        from vitaplace.engine.extension.registry import discover
        from vitaplace.engine.pipeline.plan import method_settings

        settings = method_settings(scenario, discover())
        resolved = scenario.model_dump(mode="json")
        for method in resolved["methods"]:
            method["params"] = {**settings[method["name"]]["params"], **settings[method["name"]]["defaults"]}
    print(yaml.safe_dump(resolved, sort_keys=False), end="")
    return 0


def import_command(args: argparse.Namespace) -> int:
    """`vitaplace import SRC --out RUN.h5`: a MultiPredNet-layout folder as a run file."""
    from vitaplace.engine.data.dataset import DatasetError, write_run
    from vitaplace.engine.data.matimport import import_mat

    if args.out.is_dir():
        raise DatasetError(f"--out {args.out}: is a folder; expected the run file to write "
                           f"(e.g. {args.out / 'run.h5'})")
    if args.out.exists() and not args.replace:
        raise DatasetError(f"--out {args.out}: exists; --replace writes the run file over it, or give another --out")
    run = import_mat(args.source, name=args.name, image_range=args.image_range, pose_layout=args.pose_layout,
                     tactile_model=args.tactile_model)
    try:
        path = write_run(args.out, run)
    except OSError as exc:
        raise DatasetError(f"--out {args.out}: cannot write ({exc.strerror or exc})") from None
    print(f"imported {len(run)} samples from {args.source} into {path}")
    return 0


def sweep_command(args: argparse.Namespace) -> int:
    """`vitaplace sweep SCENARIO`: every seed (and grid point) run, then the summary; exit 1 if a seed failed."""
    from vitaplace.engine.cli.slurm import check_queue_clear, settings_from_args
    from vitaplace.engine.cli.sweep import check_placement, load_sweep_scenario, run_sweep
    from vitaplace.engine.study.grid import check_seeds, check_size, grid_points, load_points, parse_axes
    from vitaplace.engine.study.summary import cell

    if args.cpus_per_job <= 0 or args.gpus_per_job < 0:
        raise UserError("--cpus-per-job must be > 0 and --gpus-per-job >= 0")
    if args.workers is not None and args.workers < 1:
        raise UserError(f"--workers {args.workers}: expected a number of worker processes, at least 1")
    slurm = settings_from_args(args)
    check_placement(args.workers, args.ray, slurm, args.gpus_per_job)
    check_seeds(args.seeds)
    axes = parse_axes(args.grid, args.overrides)
    check_size(axes, len(args.seeds), args.yes)
    scenario, resolved = load_sweep_scenario(args.scenario, args.overrides, args.gpus_per_job)
    grid = load_points(grid_points(axes), lambda point: load_sweep_scenario(
        args.scenario, [*args.overrides, *point], args.gpus_per_job), not args.no_progress) if axes else []
    log = logging.getLogger("vitaplace")
    out = Path(args.out or Path("runs") / f"{scenario.name}-sweep")
    if slurm is not None and slurm.cluster == "slurm":
        check_queue_clear(out / "slurm")  # before claiming OUT cleans files its tasks may be writing
    with claimed(out, _setup_logging) as out:
        refuse_other(out, "summary")
        outcome = run_sweep(
            scenario, resolved, args.seeds, out, args.workers, args.ray, not args.no_progress,
            _forced(args.force, "report", "sweep"),
            args.cpus_per_job, args.gpus_per_job, slurm, grid, args.replace,
        )
    for summary in outcome.summary:  # sweep.csv's rows, one per method, cell and metric
        if summary["metric"] == "max_f1":
            log.info("%s%-6s %-12s %-20s max F1 %s", f"{summary['point']} " if grid else "", summary["environment"],
                     summary["method"], summary["direction"], cell(summary))
    table, runs = out / ("grid.md" if grid else "sweep.md"), len(args.seeds) * max(1, len(grid))
    what = f"{runs} runs ({len(grid)} points x {len(args.seeds)} seeds)" if grid else f"{runs} seeds"
    if outcome.failed:
        log.error("%d of %s failed, missing from the summary: %s; summary of the others in %s",
                  len(outcome.failed), what, " ".join(map(str, sorted(outcome.failed))), table)
        return EXIT_SEEDS_FAILED
    log.info("summary of %s in %s", what, table)
    return 0


def aggregate_command(args: argparse.Namespace) -> int:
    """`vitaplace aggregate DIR...`: the summary of run folders made apart."""
    from vitaplace.engine.study.aggregate import aggregate_runs

    if args.out is not None:
        refuse_foreign(args.out, ("sweep.json",))
        refuse_other(args.out, "summary")
    out, record = aggregate_runs(args.folders, args.out)
    print(f"summary of {len(record['seeds'])} seeds in {out / 'sweep.md'}")
    return 0


def sensitivity_command(args: argparse.Namespace) -> int:
    """`vitaplace sensitivity DIR`: saved evaluations rescored; exit 1 when a failed seed was left out."""
    from vitaplace.engine.study.sensitivity import write_sensitivity

    if args.out is not None and Path(args.out).resolve() != Path(args.folder).resolve():
        refuse_foreign(args.out, ("sensitivity.json",))
    if args.out is not None and Path(args.out).resolve() != Path(args.folder).resolve() and holder(args.out):
        raise OutputDirError(f"--out {args.out}: holds another command's finished output; sensitivity writes into "
                             "the folder it rescores (without --out) or into a folder of its own")
    grid = {"taus": args.tau, "heading_tolerance_deg": args.heading_tolerance, "sequence_length": args.sequence_length}
    out, record = write_sensitivity(args.folder, args.out, **{k: v for k, v in grid.items() if v is not None})
    print(f"sensitivity of {len(record['seeds'])} seed(s) in {out / 'sensitivity.md'}")
    return EXIT_SEEDS_FAILED if record["failed"] else 0


def view_command(args: argparse.Namespace) -> int:
    """`vitaplace view ENV`: MuJoCo's interactive viewer on the environment."""
    from vitaplace.engine.sim.viewer import view

    view(args.environment)
    return 0


def video_command(args: argparse.Namespace) -> int:
    """`vitaplace video RUN.h5`: an animation of a recorded run."""
    from vitaplace.engine.data.dataset import open_run
    from vitaplace.engine.sim.video import write_video

    if args.step is not None and args.step < 1:
        raise UserError(f"--step {args.step}: expected a whole number >= 1")
    out = args.out or args.run.with_suffix(".gif")
    if out.is_file() and not args.replace:
        raise OutputDirError(f"--out {out}: exists; --replace draws the video over it, or give another --out")
    path, frames = write_video(open_run(args.run), out, args.fps, args.step)
    print(f"wrote {frames} frames to {path}")
    return 0
