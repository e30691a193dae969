"""Scenario values of the right type but outside what they can mean, refused by `vitaplace
validate` in one line naming the key path (exit 2): booleans where numbers are expected, a
negative acceptance threshold, recall@K with a K given twice or not below the references, a
fusion's or complementarity pair's vision or touch role given a method of other senses, a
training run that is an evaluation's query recording (a reference recording: a warning)."""

from __future__ import annotations

import json
import shutil
import typing
from pathlib import Path

import numpy as np
import pydantic
import pytest
import yaml

from vitaplace.engine.base.configfile import NumbersNotBooleans
from vitaplace.engine.cli.main import main
from vitaplace.engine.config.scenario import Scenario
from vitaplace.engine.data.dataset import Run, write_run
from vitaplace.engine.sim.environment import EnvironmentSpec


def refusal(capsys, *settings: str) -> str:
    """The one line `vitaplace validate quickstart --set ...` refuses ``settings`` with (exit 2)."""
    assert main(["validate", "quickstart", *[a for s in settings for a in ("--set", s)]]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    return lines[0]


@pytest.mark.parametrize("setting, where, wanted", [
    ("seed=false", "seed", "a whole number"),
    ("train.run.n_samples=true", "train.run.n_samples", "a whole number"),
    ("evaluations.0.run.n_samples=true", "evaluations.0.run.n_samples", "a whole number"),
    ("robot.deflection_samples=true", "robot.deflection_samples", "a whole number"),
    ("scoring.recall_k=[1, true]", "scoring.recall_k.1", "a whole number"),
    ("scoring.sequence.length=true", "scoring.sequence.length", "a whole number"),
    ("methods.0.params.epochs=true", "methods.0.params: extractor 'mupnet': epochs", "a whole number"),
    ("methods.0.params.image_size=[12, true]", "methods.0.params: extractor 'mupnet': image_size.1", "a whole number"),
    ("methods.1.params.grid=[true, 64]", "methods.1.params: extractor 'handcrafted': grid.0", "a whole number"),
    ("scoring.tau=true", "scoring.tau", "a number"),
    ("evaluations.0.query_off_route=true", "evaluations.0.query_off_route", "a number"),
    ("train.run.gains.attend_margin_share=true", "train.run.gains.attend_margin_share", "a number"),
    ("robot.whisk_hz=true", "robot.whisk_hz", "a number"),
    ("methods.0.params.latent_prior=true", "methods.0.params: extractor 'mupnet': latent_prior", "a number"),
])
def test_a_boolean_for_a_number_is_one_line(capsys, setting, where, wanted):
    """YAML's true is not 1: pydantic would read `epochs: true` as one epoch."""
    line = refusal(capsys, setting)
    assert f"quickstart.yaml: {where}: expected {wanted}, not a boolean" in line, line


def test_a_key_that_takes_a_boolean_still_does(capsys):
    assert main(["validate", "quickstart", "--set", "report.pdf=true"]) == 0

    class Either(NumbersNotBooleans):
        flag: bool | int = 0
        anything: typing.Any = None
        count: int = 0

    assert Either(flag=True, anything=False).model_dump() == {"flag": True, "anything": False, "count": 0}
    with pytest.raises(pydantic.ValidationError, match="count\n  expected a whole number, not a boolean"):
        Either(count=True)


def test_a_negative_delta_is_one_line(capsys):
    """delta bounds the best match's distance, never negative: at -0.5 nothing is accepted and
    every method scores precision 1, recall 0, F1 0 at delta, whatever its distances."""
    line = refusal(capsys, "scoring.delta=-0.5")
    assert "quickstart.yaml: scoring.delta: Input should be greater than or equal to 0" in line, line
    assert main(["validate", "quickstart", "--set", "scoring.delta=0"]) == 0  # identical features only


def test_a_recall_k_given_twice_is_one_line(capsys):
    line = refusal(capsys, "scoring.recall_k=[1, 1, 100000]")
    assert line.endswith("quickstart.yaml: scoring.recall_k: K 1 is given more than once in [1, 1, 100000]; "
                         "expected distinct K values"), line


def test_a_recall_k_not_below_the_simulated_references_is_one_line(capsys):
    """With 40 references every query with a true match has it among its first 40: recall@40
    is 100 % for any method. K 39 still ranks."""
    line = refusal(capsys, "evaluations.0.run.n_samples=40", "scoring.recall_k=[1, 40]")
    assert line.endswith("quickstart.yaml: scoring.recall_k: K 40 is not below the 40 reference samples of "
                         "evaluation E1 (evaluations.0.run.n_samples): recall@K would count every query with a true "
                         "match as found; expected each K < 40"), line
    assert main(["validate", "quickstart", "--set", "evaluations.0.run.n_samples=40",
                 "--set", "scoring.recall_k=[1, 39]"]) == 0


def _recorded(path: Path, n: int) -> Path:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    rng = np.random.default_rng(n)
    return write_run(path, Run.from_arrays(
        images=rng.integers(0, 255, (n, 8, 8, 3), dtype=np.uint8), theta=np.zeros((n, 4)),
        xy=rng.normal(0, 0.02, (n, 4, 2)), poses=np.c_[np.cos(t), np.sin(t), t], name=path.stem))


def _recorded_evaluation(tmp_path, reference: int, scoring: dict, methods: list | None = None):
    """s.yaml in ``tmp_path``: one evaluation of recorded runs (12 training and query samples,
    ``reference`` reference samples, `_recorded`) with ``scoring`` and ``methods`` (H)."""
    files = {name: _recorded(tmp_path / f"{name}.h5", n) for name, n in (("train", 12), ("query", 12),
                                                                         ("reference", reference))}
    scenario = {"name": "recorded", "train": {"dataset": str(files["train"])},
                "evaluations": [{"name": "E1", "datasets": {"query": str(files["query"]),
                                                            "reference": str(files["reference"])}}],
                "methods": methods or [{"name": "H", "plugin": "handcrafted"}], "scoring": scoring}
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(scenario))
    return path, files


@pytest.mark.parametrize("direction, refused", [("query-to-reference", None), ("reference-to-query", "query"),
                                                ("both", "query")])
def test_a_recall_k_not_below_a_recorded_runs_references_is_one_line(tmp_path, capsys, direction, refused):
    """Recorded runs: the files' lengths. A 12-sample query and a 30-sample reference rank 20
    references searching the reference, not searching the query (reference-to-query, both)."""
    path, files = _recorded_evaluation(tmp_path, 30, {"tau": 0.5, "recall_k": [1, 20], "direction": direction})
    if refused is None:
        assert main(["validate", str(path)]) == 0
        return
    assert main(["validate", str(path)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert (f"s.yaml: scoring.recall_k: K 20 is not below the 12 reference samples of evaluation E1 "
            f"(evaluations.0.datasets.{refused} {files[refused]})") in lines[0], lines[0]


def test_the_default_recall_k_is_left_to_a_tiny_evaluation():
    """[1, 5, 10] on a five-sample evaluation (the smallest there is) validates as before."""
    assert main(["validate", "quickstart", "--set", "evaluations.0.run.n_samples=5",
                 "--set", "scoring.sequence.length=1"]) == 0


def test_the_default_recall_k_scores_only_the_k_below_the_references(tmp_path):
    """Of the default [1, 5, 10], an 8-sample reference run scores recall@1 and @5 and leaves
    @10 out (at K >= the references every query with a true match counts as found: 100 % for
    any method), with a run warning in the manifest naming the run and the K."""
    path, _ = _recorded_evaluation(tmp_path, 8, {"tau": 0.5},
                                   [{"name": "H-V", "plugin": "handcrafted", "params": {"use_tactile": False}}])
    assert main(["-q", "run", str(path), "--out", str(tmp_path / "out")]) == 0
    (row,) = json.loads((tmp_path / "out" / "results.json").read_text())
    assert sorted(row["recall_at_k"], key=int) == ["1", "5"]
    warnings = json.loads((tmp_path / "out" / "manifest.json").read_text())["warnings"]
    assert [w["recall@K"] for w in warnings.values() if "recall@K" in w] == [
        "recall@10: not scored against run 'E1/reference': K is not below its 8 samples, where every query with a "
        "true match counts as found"]


def _models(tp: typing.Any) -> set[type[pydantic.BaseModel]]:
    """The pydantic models an annotation names, through unions, containers and Annotated."""
    if isinstance(tp, type) and issubclass(tp, pydantic.BaseModel):
        return {tp}
    return set().union(*(_models(arg) for arg in typing.get_args(tp)))


def test_every_model_of_a_scenario_and_every_shipped_plugins_params_refuse_booleans_for_numbers():
    """One mechanism: the scenario's models, those they hold, and each shipped extractor's
    parameters derive from `NumbersNotBooleans` (a new model that does not is named here)."""
    from vitaplace.engine.extension.registry import discover

    seen = _held(Scenario) | {cls.Params for cls in discover().extractors.values()}
    assert len(seen) > 20
    assert sorted(m.__name__ for m in seen if not issubclass(m, NumbersNotBooleans)) == []


def _held(root: type[pydantic.BaseModel]) -> set[type[pydantic.BaseModel]]:
    """``root`` and every model its fields hold, through the models they hold."""
    seen: set[type[pydantic.BaseModel]] = set()
    todo = [root]
    while todo:
        model = todo.pop()
        if model not in seen:
            seen.add(model)
            todo += [m for f in model.model_fields.values() for m in _models(f.annotation)]
    return seen


def test_every_model_of_an_environment_refuses_booleans_for_numbers():
    """The environment file's models too (arena, walls, panels, lights, boards, landmarks, textures)."""
    seen = _held(EnvironmentSpec)
    assert len(seen) > 8
    assert sorted(m.__name__ for m in seen if not issubclass(m, NumbersNotBooleans)) == []


@pytest.mark.parametrize("setting, where, wanted", [
    ("lighting: {ambient: true}", "lighting.ambient", "a number"),
    ("arena: {wall_height: true}", "arena.wall_height", "a number"),
    ("landmarks: [{name: b, type: box, pos: [2, 0], size: [1, true, 0.3]}]", "landmarks.0.size.1", "a number"),
    ("materials: {grey: {rgba: [0.7, 0.7, 0.7, 1], texture: {builtin: checker, random: true}}}",
     "materials.grey.texture.random", "a number"),
], ids=["lighting.ambient", "arena.wall_height", "landmarks.0.size.1", "texture.random"])
def test_a_boolean_for_a_number_in_an_environment_file_is_one_line(tmp_path, capsys, setting, where, wanted):
    """`ambient: true` was read as full ambient light, a landmark's size 1 m."""
    path = tmp_path / "env.yaml"
    path.write_text(f"extends: e1\n{setting}\n")
    assert main(["validate", str(path)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert f"env.yaml: {where}: expected {wanted}, not a boolean" in lines[0], lines[0]
    path.write_text("extends: e1\nlighting: {shadows: true}\n")  # a key that takes a boolean still does
    assert main(["validate", str(path)]) == 0


#: quickstart's methods as vision-only, touch-only and both-senses configurations, and one
#: whose plugin declares no senses (the autoencoder)
ROLE_METHODS = ('methods=[{name: H-V, plugin: handcrafted, params: {use_tactile: false}}, '
                '{name: H-T, plugin: handcrafted, params: {use_visual: false}}, {name: H, plugin: handcrafted}, '
                '{name: L-V, plugin: mupnet, params: {modalities: [visual], epochs: 1}}, '
                '{name: A, plugin: autoencoder}]')


@pytest.mark.parametrize("setting, line", [
    ("scoring.complementarity=[{vision: H-T, touch: H-V}]",
     "scoring.complementarity.0.vision: method H-T uses tactile (as its plugin 'handcrafted' declares it); "
     "the vision method needs visual alone (a vision-only method)"),
    ("fusions=[{name: F, vision: H-V, touch: L-V}]",
     "fusions.0.touch: method L-V uses visual (as its plugin 'mupnet' declares it); "
     "the touch method needs tactile alone (a touch-only method)"),
    ("scoring.complementarity=[{vision: H-V, touch: H-T}, {vision: H, touch: H-T}]",
     "scoring.complementarity.1.vision: method H uses visual and tactile (as its plugin 'handcrafted' declares "
     "it); the vision method needs visual alone (a vision-only method)"),
    ("fusions=[{name: F, vision: H-V, touch: H}]",
     "fusions.0.touch: method H uses visual and tactile (as its plugin 'handcrafted' declares it); "
     "the touch method needs tactile alone (a touch-only method)"),
], ids=["touch as vision", "vision as touch", "both as vision", "both as touch"])
def test_a_role_given_a_method_of_the_wrong_senses_is_one_line(capsys, setting, line):
    """A fusion and a complementarity pair put a vision-only code beside a touch-only one
    (docs/DESIGN.md): touch-only H-T as the vision half would report touch rescuing "vision",
    and H, with both senses, would make the "vision code + w touch code" control a joint code."""
    assert refusal(capsys, ROLE_METHODS, setting).endswith(f"quickstart.yaml: {line}")


@pytest.mark.parametrize("setting", [
    "scoring.complementarity=[{vision: H-V, touch: H-T}, {vision: L-V, touch: H-T}]",
    "fusions=[{name: F, vision: L-V, touch: H-T}, {name: G, vision: A, touch: H-T}, {name: K, vision: H-V, touch: A}]",
], ids=["complementarity", "fusions"])
def test_roles_of_the_right_or_undeclared_senses_still_validate(setting):
    """A plugin that declares no senses (the autoencoder) cannot be checked: accepted in either role."""
    assert main(["validate", "quickstart", "--set", ROLE_METHODS, "--set", setting]) == 0


def _recorded_scenario(tmp_path: Path, train: str) -> Path:
    """A recorded scenario whose training run is a copy of its query run (``train: query``),
    a link to its reference run (``reference``), or a recording of its own (``own``)."""
    files = {name: _recorded(tmp_path / f"{name}.h5", n) for name, n in (("own", 12), ("query", 12),
                                                                         ("reference", 30))}
    if train == "query":
        shutil.copy(files["query"], tmp_path / "train.h5")
    elif train == "reference":
        (tmp_path / "train.h5").symlink_to(files["reference"])
    else:
        (tmp_path / "train.h5").symlink_to(files["own"])
    scenario = {"name": "recorded", "train": {"dataset": "train.h5"},
                "evaluations": [{"name": "E1", "datasets": {"query": "query.h5", "reference": "reference.h5"}}],
                "methods": [{"name": "H", "plugin": "handcrafted"}], "scoring": {"tau": 0.5}}
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(scenario))
    return path


def test_training_on_an_evaluations_query_recording_is_one_line(tmp_path, capsys):
    """Fitted on the queries it is scored on, a method learns the answers: leakage. A copy is
    the same recording (by content, as query and reference are compared)."""
    assert main(["validate", str(_recorded_scenario(tmp_path, "query"))]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert lines[0].endswith(f"s.yaml: train.dataset {tmp_path / 'train.h5'} is the same recording as "
                             f"evaluations.0.datasets.query {tmp_path / 'query.h5'}: the methods would be fitted on "
                             "the queries evaluation E1 scores; expected a training run of its own"), lines[0]


@pytest.mark.parametrize("train, warned", [("reference", True), ("own", False)])
def test_training_on_an_evaluations_reference_recording_is_warned_about(tmp_path, capsys, train, warned):
    """Building the map from the reference traverse can be a design, so it runs, but says so."""
    assert main(["validate", str(_recorded_scenario(tmp_path, train))]) == 0
    err = capsys.readouterr().err
    # the link is read as the file it names
    said = (f"s.yaml: train.dataset {tmp_path / 'reference.h5'} is the same recording as evaluations.0.datasets."
            f"reference {tmp_path / 'reference.h5'}: the methods are fitted on the run evaluation E1 searches")
    assert (said in err) == warned, err
    assert ("same recording" in err) == warned, err


@pytest.mark.parametrize("train, warned", [("reference", True), ("own", False)])
def test_a_run_trained_on_a_reference_recording_says_so_in_its_manifest_and_report(tmp_path, capsys, train,
                                                                                   warned):
    """The warning of `validate` reaches what a reader of the results reads, and the console
    says it once."""
    out = tmp_path / "out"
    assert main(["-q", "run", str(_recorded_scenario(tmp_path, train)), "--out", str(out)]) == 0
    assert capsys.readouterr().err.count("same recording") == warned
    said = ("run train is the same recording as E1/reference: the methods are fitted on the run evaluation E1 "
            "searches, so its scores measure recognising places of the training run itself")
    warnings = json.loads((out / "manifest.json").read_text())["warnings"]
    assert (warnings.get("train", {}).get("trained on E1/reference") == said) == warned, warnings
    assert (said in " ".join((out / "report.md").read_text().split())) == warned


@pytest.mark.parametrize("tau, refused", [(2.8, False), (2.9, True)])
def test_tau_of_a_recorded_evaluation_without_a_world_is_bounded_by_its_poses(tmp_path, capsys, tau, refused):
    """No arena to bound tau by: the box around the poses the query and reference runs
    recorded (both on the unit circle: 2 x 2 m, diagonal 2.83 m) is. At or beyond its diagonal
    every pair of poses would count as a revisit, and any method would score 100 %."""
    path, _ = _recorded_evaluation(tmp_path, 30, {"tau": tau, "recall_k": [1], "heading_tolerance_deg": None})
    assert main(["validate", str(path)]) == (2 if refused else 0)
    lines = capsys.readouterr().err.strip().splitlines()
    if refused:
        assert lines == [f"vitaplace: error: {path}: scoring.tau: {tau} m is not below the 2.83 m diagonal of the box "
                         "of the poses evaluations.0.datasets recorded: every pair of poses would count as a revisit"]


@pytest.mark.parametrize("params, message", [
    ("{use_tactile: false, pfh_bins: 5, sda_mode: per_axis}",
     "pfh_bins, sda_mode are ignored with use_tactile false (only the term it switches off reads them); leave them "
     "out or set use_tactile true"),
    ("{use_visual: false, grid: [10, 20]}",
     "grid is ignored with use_visual false (only the term it switches off reads it); leave it out or set "
     "use_visual true"),
])
def test_a_hand_crafted_setting_of_a_term_switched_off_is_refused(capsys, params, message):
    """Each term reads its own settings: one given for a term switched off would be silently
    ignored. A default value (as `vitaplace config --resolved` writes every key) is accepted."""
    assert main(["validate", "quickstart", "--set", f"methods.1.params={params}"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].endswith(f"methods.1.params: extractor 'handcrafted': {message}"), lines
    assert main(["validate", "quickstart", "--set", "methods.1.params={use_tactile: false, pfh_bins: 3}"]) == 0


@pytest.mark.parametrize("sets, message", [
    (["robot.tactile_model=penetration", "robot.whisker_friction=0.9"],
     "robot: whisker_friction 0.9 is ignored by tactile_model penetration (its whiskers pass through objects without "
     "friction); leave it out or choose physical"),
    (["report.pdf=true", "report.figures=none"],
     "report: pdf true draws each figure as a PDF too, and figures none draws none; set figures to all or summary, "
     "or leave pdf out"),
])
def test_a_setting_the_other_settings_leave_unread_is_refused(capsys, sets, message):
    """A simulation with penetration whiskers has no shaft friction (its runs are bit for bit
    the same at any), a report without figures draws no PDF: a value given would be ignored."""
    assert main(["validate", "quickstart", *sum((["--set", s] for s in sets), [])]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].endswith(message), lines
    assert main(["validate", "quickstart", "--set", sets[0]]) == 0  # either alone is fine


@pytest.mark.parametrize("sets, message", [
    (["fusions=[{name: F, vision: H, touch: H, weights: [0, 1.0e+13]}]"],
     "fusions.0.weights: weight 1e+13: expected at most 1e+12 (beyond, the vision term is lost in the rounding of "
     "the fused sum, and the sum can overflow)"),
    (["scoring.sequence.velocity_steps=100000000"], "scoring.sequence.velocity_steps: "),
])
def test_settings_past_what_the_arithmetic_or_the_time_allows_are_refused(capsys, sets, message):
    """A touch weight of 1e308 overflowed the fused distances (a max F1 from +inf); 1e8
    velocities per sequence ran for hours: each refused at validation in one line."""
    assert main(["validate", "quickstart", *sum((["--set", s] for s in sets), [])]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], lines


@pytest.mark.parametrize("sets, message", [
    (["train.run.start=[0, 0, 1e308]"], "train.run.start.2: Input should be less than or equal to 360"),
    (["fusions=[{name: F, vision: H, touch: L}, {name: F, vision: H, touch: L}]"],
     "fusions.1.name: 'F' is already a method's or another fusion's name"),  # the second is the repeat
])
def test_values_refused_at_validation_name_the_entry_at_fault(capsys, sets, message):
    """A start's yaw of 1e308 validated and the simulation then failed as 'unstable', blaming
    the robot; a repeated fusion name was reported at the first of the two."""
    assert main(["validate", "quickstart", *sum((["--set", s] for s in sets), [])]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], lines


def test_a_negative_rock_seed_is_refused_naming_it(tmp_path, capsys):
    """MuJoCo refused it when compiling ('expected non-negative integer'), naming nothing."""
    env = yaml.safe_load((Path(__file__).resolve().parents[2] / "scenarios" / "environments" / "e1.yaml").read_text())
    env["landmarks"] = [{"type": "rock", "pos": [1, 1], "size": [0.5, 0.5, 0.5], "seed": -5}]
    path = tmp_path / "rocks.yaml"
    path.write_text(yaml.safe_dump(env))
    assert main(["validate", str(path)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "landmarks.0" in lines[0] and "seed" in lines[0], lines


def test_a_start_inside_a_landmark_is_refused_naming_it(tmp_path, capsys):
    """A landmark on the foraging start failed after simulating as 'the robot never moved'.
    E1's east box is centred at (2.138, 0); the originals' E2 and E3 starts, whose body disc
    touches a landmark by 2-4 cm, stay valid."""
    path = tmp_path / "env.yaml"
    path.write_text("extends: e1\nstart: [2.138, 0.0, 0.0]\n")
    assert main(["validate", str(path)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    assert "env.yaml: start: (2.138, 0) is inside a landmark; expected free floor" in lines[0], lines
    path.write_text("extends: e1\nstart: [1.5, 0.0, 0.0]\n")  # 0.4 m short of the box: free floor
    assert main(["validate", str(path)]) == 0
    for name in ("e2", "e3"):
        assert main(["validate", name]) == 0


@pytest.mark.parametrize("arena, refused", [({"width": 3}, "width alone"), ({"depth": 4}, "depth alone"),
                                            ({"width": 3, "depth": 4}, None)])
def test_a_rectangular_arena_needs_both_sides(tmp_path, capsys, arena, refused):
    """One side alone validated as a rectangle whose other side silently came from ``size``."""
    env = yaml.safe_load((Path(__file__).resolve().parents[2] / "scenarios" / "environments" / "e1.yaml").read_text())
    env["arena"] = {**env.get("arena", {}), **arena}
    env.pop("landmarks", None), env.pop("route", None)
    path = tmp_path / "arena.yaml"
    path.write_text(yaml.safe_dump(env))
    assert main(["validate", str(path)]) == (2 if refused else 0)
    if refused:
        lines = capsys.readouterr().err.strip().splitlines()
        assert len(lines) == 1 and "arena" in lines[0] and refused in lines[0], lines
