"""Command-line interface: ``vitaplace COMMAND``, COMMAND one of ``run|validate|config|
simulate|train|evaluate|report|difficulty|export|plugins|sweep|aggregate|sensitivity|import|view|video``.

User errors (bad scenario, missing file, unknown plugin, corrupt dataset, diverged
training) print one line ``vitaplace: error: ...`` and exit with code 2, no traceback.
A plugin's ``fit``, ``transform`` or ``distance`` that raises prints one line naming the stage,
method, plugin and error and exits with 1, its traceback in ``OUT/error.txt``.
A sweep in which some seeds failed writes the summary of the others and exits with 1.

Every command takes ``-v`` (debug messages too) or ``-q`` (warnings and errors only, no
progress bars), before or after its name; messages go to stderr (and ``OUT/log.txt``, which
keeps every info line), so ``run --json`` (and ``difficulty --json``) leaves only the JSON on stdout. With
shtab installed (``pip install "vitaplace[completion]"``), ``vitaplace --print-completion
bash`` prints a shell completion script.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn, TextIO

from vitaplace.engine import __version__
from vitaplace.engine.base.cpus import configure_blas_threads
from vitaplace.engine.base.errors import UserError
from vitaplace.engine.cli.commands import (
    aggregate_command,
    config_command,
    difficulty_command,
    evaluate_command,
    export_command,
    import_command,
    plugins_command,
    report_command,
    run_command,
    sensitivity_command,
    simulate_command,
    sweep_command,
    train_command,
    validate_command,
    video_command,
    view_command,
)

EXIT_USER_ERROR = 2
#: a plugin's fit, transform or distance raised (a bug of the plugin, not bad input): one line, the
#: traceback in OUT/error.txt
EXIT_PLUGIN_FAILED = 1
#: what each command's subparser names as its ``handler``: parsed arguments -> exit code
Handler = Callable[[argparse.Namespace], int]


class _Parser(argparse.ArgumentParser):
    """argparse's parser whose usage error is one line, as every other error of the command
    line: ``vitaplace: error: MESSAGE (see `PROG --help`)``, exit 2 (not the usage block)."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USER_ERROR, f"vitaplace: error: {one_line(message)} (see `{self.prog} --help`)\n")


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


def _add_scenario_args(parser: argparse.ArgumentParser, out: bool = True,
                       out_help: str = "output directory (default: runs/<scenario name>)") -> None:
    parser.add_argument("scenario", help="scenario YAML file, or the name of a built-in one (e.g. quickstart)")
    parser.add_argument(
        "--set", dest="overrides", action="append", default=[], metavar="KEY.PATH=VALUE",
        help="override a scenario value, e.g. --set methods.0.params.epochs=2; KEY.PATH+=VALUE appends to a "
        "list, e.g. --set 'methods+={name: L2, plugin: mupnet}' (VALUE is YAML; repeatable)",
    )
    if out:
        parser.add_argument("--out", type=Path, help=out_help)
        parser.add_argument(
            "--force", action="append", nargs="?", const="all", default=[], metavar="STAGE",
            help="redo a stage even if cached: simulate, fit, transform, evaluate, report (repeatable); "
            "--force alone (or --force all) redoes every stage the command runs",
        )
        parser.add_argument("--no-progress", action="store_true", help="no progress bars")


def build_parser() -> argparse.ArgumentParser:
    """The ``vitaplace`` parser; each command's ``handler`` default is the function that runs it."""
    common = _verbosity()
    parser = _Parser(
        prog="vitaplace",
        description="Visuo-tactile place recognition with a simulated whiskered robot (MuPNet vs ViTa-SLAM).",
        parents=[common],
    )
    parser.add_argument("--version", action="version", version=f"vitaplace {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_stage_commands(sub, common)
    _add_inspection_commands(sub, common)
    _add_import_command(sub, common)
    _add_export_command(sub, common)
    _add_sweep_command(sub, common)
    _add_study_commands(sub, common)
    _add_viewing_commands(sub, common)
    _add_completion(parser)
    return parser


def _add_stage_commands(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """The commands that run the pipeline's stages: ``run|simulate|train|evaluate|report`` and ``difficulty``."""
    stages = {
        "run": ("run the whole pipeline and write the report", run_command),
        "simulate": ("record the scenario's datasets (HDF5), or one foraging run of an environment file",
                     simulate_command),
        "train": ("simulate, then fit every method on the training run", train_command),
        "evaluate": ("everything up to the evaluation: results.json and results.csv", evaluate_command),
        "report": ("everything, then (re)write the report (cached stages reused); `report OUT`: rebuild it from OUT",
                   report_command),
    }
    for name, (help_text, handler) in stages.items():
        p = sub.add_parser(name, help=help_text, description=help_text, parents=[common])
        p.set_defaults(handler=handler)
        _add_scenario_args(p)
        if name in ("run", "evaluate", "report"):
            p.add_argument("--json", action="store_true", help="print the results rows as JSON on stdout")
        if name == "simulate":
            p.add_argument("--samples", type=int, help="environment file only: number of samples (default 200)")
            p.add_argument("--seed", type=int,
                           help="environment file only: run seed, 0 <= seed < 2**32 as a scenario's (default 0)")
            p.add_argument("--replace", action="store_true",
                           help="environment file only: replace the run file of that environment and seed in --out "
                                "(refused without it)")
    p = sub.add_parser(
        "difficulty", parents=[common],
        help="whether touch can matter: the touch measures and H-V/H-T complementarity of every evaluation against "
        "its gates, with the hand-crafted methods only (the scenario's methods are not run)",
    )
    p.set_defaults(handler=difficulty_command)
    _add_scenario_args(p, out_help="the run (or sweep) folder whose cached stages it reuses; it writes OUT/difficulty/ "
                                   "(default: runs/<scenario name>)")
    p.add_argument("--json", action="store_true",
                   help="print one JSON row per evaluation and direction on stdout "
                        "(difficulty, complementarity, gates)")


def _add_inspection_commands(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``validate`` and ``config`` (a scenario or environment file, nothing run) and ``plugins``."""
    p = sub.add_parser(
        "validate", parents=[common],
        help="check a scenario or an environment file (or a shipped one by name) without running anything",
    )
    p.set_defaults(handler=validate_command)
    _add_scenario_args(p, out=False)
    p = sub.add_parser("config", parents=[common],
                       help="print the resolved scenario as YAML: what run would use (extends merged, --set applied)")
    p.set_defaults(handler=config_command)
    _add_scenario_args(p, out=False)
    p.add_argument("--resolved", action="store_true",
                   help="every setting, the defaults the scenario leaves out filled in (each method's parameters "
                   "too, as its plugin resolves them)")
    p = sub.add_parser("plugins", parents=[common],
                       help="list the feature-extractor plugins and any that failed to load")
    p.set_defaults(handler=plugins_command)


def _add_import_command(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``import SRC --out RUN.h5``: a MultiPredNet/WhiskEye MATLAB folder as a run file."""
    p = sub.add_parser(
        "import", parents=[common], help="convert a MultiPredNet/WhiskEye MATLAB folder into a run file (HDF5)"
    )
    p.set_defaults(handler=import_command)
    p.add_argument("source", type=Path, help="folder with images.mat, theta.mat, xy.mat and poses.mat")
    p.add_argument("--out", type=Path, required=True, help="the run file to write (e.g. runs/real/query.h5)")
    p.add_argument("--name", help="name of the run (default: the folder's name)")
    p.add_argument("--image-range", choices=("0-1", "0-255"),
                   help="range of float images when the data cannot tell (0-1 saturates values above 1)")
    p.add_argument("--pose-layout", choices=("Nx3", "3xN"), help="layout of a 3 x 3 pose array (three samples)")
    p.add_argument("--tactile-model", choices=("physical", "penetration"), default="physical",
                   help="what the whiskers' xy are: physical (sprung whiskers, MultiPredNet's Gazebo WhiskEye; the "
                   "default) or penetration (docs/SIMULATION.md); recorded in the run file")
    p.add_argument("--replace", action="store_true", help="write over an existing --out file (refused without it)")


def _add_export_command(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``export SCENARIO --out DIR``: the scenario's runs as data other tools read (docs/DATA.md)."""
    p = sub.add_parser("export", parents=[common],
                       help="write a scenario's evaluations as VPR image folders with ground truth, and its runs as a "
                       "checksummed package (docs/DATA.md)")
    p.set_defaults(handler=export_command)
    _add_scenario_args(p, out=False)
    p.add_argument("--out", type=Path, required=True, help="the folder to write (empty, or an export of this format)")
    p.add_argument("--format", choices=("vpr", "package", "both"), default="both",
                   help="vpr: image folders and positives per evaluation; package: run files, ground truth, "
                   "datasheet and checksums; both (the default)")
    p.add_argument("--runs", type=Path, help="where the runs are recorded and cached, as `vitaplace simulate` "
                   "does (default: runs/<scenario name>-export)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


def _add_study_commands(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """``aggregate`` and ``sensitivity``: over run folders already made."""
    p = sub.add_parser(
        "aggregate", parents=[common],
        help="summarise run folders of one scenario made by independent jobs (e.g. a SLURM array)",
    )
    p.set_defaults(handler=aggregate_command)
    p.add_argument("folders", nargs="+", type=Path, metavar="DIR",
                   help="run folders (vitaplace run --set seed=N --out DIR)")
    p.add_argument("--out", type=Path, help="where the summary goes (default: the folders' common parent)")
    p = sub.add_parser(
        "sensitivity", parents=[common],
        help="rescore a run's or sweep's saved evaluations for other revisit and heading tolerances",
    )
    p.set_defaults(handler=sensitivity_command)
    p.add_argument("folder", type=Path, metavar="DIR", help="a finished run folder or a sweep folder (seed-*/)")
    p.add_argument("--tau", type=float, nargs="+",
                   help="revisit tolerances in metres, each once and below the arenas' diagonals (default 0.2 0.3 0.5)")
    p.add_argument("--heading-tolerance", type=float, metavar="DEG",
                   help="heading tolerance scored beside position only (default 30)")
    p.add_argument("--sequence-length", type=int, metavar="L",
                   help="score sequences of L queries (SeqSLAM, docs/DESIGN.md) instead of what the run scored")
    p.add_argument("--out", type=Path, help="where sensitivity.csv/.md/.json go (default: DIR)")


def _add_sweep_command(sub: argparse._SubParsersAction, common: argparse.ArgumentParser) -> None:
    """`vitaplace sweep`: seeds, and where they run (local pool, Ray, SLURM) with what each reserves."""
    p = sub.add_parser("sweep", parents=[common],
                       help="run a scenario over several seeds (local process pool, Ray or SLURM)")
    p.set_defaults(handler=sweep_command)
    _add_scenario_args(p)
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="scenario seeds to run")
    p.add_argument(
        "--grid", action="append", default=[], metavar="KEY.PATH=V1,V2,...",
        help="run every seed at each value of a --set path, e.g. --grid methods.0.params.epochs=30,90,270 (values "
        "parsed as YAML; several --grid options form their product; one folder OUT/<path end>=<value> per grid point)",
    )
    p.add_argument("--replace", action="store_true",
                   help="replace a summary in --out that covers seeds or grid points this sweep lacks "
                        "(refused without it)")
    p.add_argument("--yes", action="store_true",
                   help="run a grid of more than 1000 points (refused without it)")
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
    p.set_defaults(handler=view_command)
    p.add_argument("environment", help="environment YAML file, or the name of a shipped one (e.g. e1)")
    p = sub.add_parser("video", parents=[common],
                       help="animate a recorded run: camera frames, top view with trajectory, whisker contacts")
    p.set_defaults(handler=video_command)
    p.add_argument("run", type=Path, help="run file (HDF5), e.g. from `vitaplace simulate ENV.yaml`")
    p.add_argument("--out", type=Path, help="the video to write, .gif (always) or .mp4 (needs ffmpeg); default RUN.gif")
    p.add_argument("--fps", type=float, default=5.0,
                   help="frames per second, 0.1 to 50 (default 5; one sample per 0.5 s whisk cycle)")
    p.add_argument("--step", type=int, help="draw every STEP-th sample (default 1, or larger to keep to 300 frames)")
    p.add_argument("--replace", action="store_true", help="write over an existing video (refused without it)")


def _add_completion(parser: argparse.ArgumentParser) -> None:
    """``--print-completion bash|zsh|tcsh`` where the optional shtab is installed."""
    try:
        import shtab
    except ImportError:
        return
    shtab.add_argument_to(parser, ["--print-completion"], help="print a shell completion script")


class _StderrHandler(logging.StreamHandler):
    """A handler that writes to ``sys.stderr`` as it is when a message comes (redirections work)."""

    @property
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
    handler: Handler = args.handler
    try:
        configure_blas_threads()
        return handler(args)
    except UserError as exc:
        print(f"vitaplace: error: {one_line(str(exc))}", file=sys.stderr)
        return EXIT_USER_ERROR
    except Exception as exc:
        from vitaplace.engine.pipeline.output_checks import plugin_failure  # only when something failed

        line = plugin_failure(exc)
        if line is not None:
            print(f"vitaplace: error: {one_line(line)}", file=sys.stderr)
            return EXIT_PLUGIN_FAILED
        if isinstance(exc, OSError) and exc.filename is not None:  # a path the system refused (too long, denied)
            print(f"vitaplace: error: {one_line(str(exc.filename))}: {exc.strerror or exc}", file=sys.stderr)
            return EXIT_USER_ERROR
        raise


def one_line(message: str) -> str:
    """``message`` with its unprintable characters (a line break, a tab, an escape) written as
    Python writes them in a string (``\\n``), so that an error stays the one line it says it is
    whatever a value it quotes holds (an environment variable, a file name)."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in message)


if __name__ == "__main__":
    sys.exit(main())
