"""Reports and figures say what they show: colour scales, bands, overlapping PR curves, AUC,
the test-time inference cap, recorded inputs and features that carried nothing, provenance."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from importlib.metadata import version
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
import yaml

from vitaplace.engine.data.dataset import Run, write_run
from vitaplace.engine.evaluation import evaluate as ev
from vitaplace.engine.report import figures


@pytest.fixture
def drawn(monkeypatch) -> list:
    """The figures the plot functions draw, instead of saving them."""
    figs: list = []
    monkeypatch.setattr(figures, "_save", lambda fig, stem, formats=(): figs.append(fig) or [])
    return figs


def _circle_case(n: int = 40):
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    poses = np.c_[np.cos(t), np.sin(t), t]
    gtm = ev.ground_truth_matrix(poses, poses)
    return poses, gtm


def test_tme_colours_span_its_bulk_not_its_outliers_and_the_colour_bar_says_so(tmp_path, drawn):
    _, gtm = _circle_case(100)
    rng = np.random.default_rng(0)
    tme = rng.uniform(0.0, 0.01, gtm.shape)
    tme[[5, 50, 77]] = 0.5  # three far-off queries: 3 % of the entries
    decisions = ev.decide(tme, gtm, 0.3, 0.005)
    figures.plot_matrices(tmp_path / "m", tme, gtm, decisions)
    gtm_ax, tme_ax = [ax for ax in drawn[0].axes if not hasattr(ax, "_colorbar")]
    low, high = tme_ax.images[0].get_clim()
    # the bulk is uniform on [0, 0.01]: its 1st percentile is near 0, the 90th near 0.009
    assert 0.0 <= low < 0.0005 and 0.008 < high < 0.0101
    assert gtm_ax.images[0].get_clim() == pytest.approx((gtm.min(), gtm.max()))  # ground truth: full range
    labels = [ax.get_ylabel() for ax in drawn[0].axes if hasattr(ax, "_colorbar")]
    assert "percentile" in labels[1] and "percentile" not in labels[0]


def test_pr_curves_that_coincide_both_show(tmp_path, drawn):
    _, gtm = _circle_case()
    perfect = ev.pr_curve(gtm, gtm, 0.3)
    figures.plot_pr_curves(tmp_path / "p", {"L": perfect, "H": perfect, "X": perfect})
    ax = drawn[0].axes[0]
    curves = [line for line in ax.get_lines() if line.get_label()[:1] in "LHX" and line.get_linestyle() != "None"]
    assert len(curves) == 3
    assert len({line.get_linestyle() for line in curves}) == 3  # each its own dash pattern
    widths = [line.get_linewidth() for line in curves]
    assert widths[0] > widths[1] > widths[2]  # the first drawn is widest ...
    orders = [line.get_zorder() for line in curves]
    assert orders[0] < orders[1] < orders[2]  # ... and lowest, so the later ones stay visible on it
    assert "AUC: step-wise average precision" in drawn[0].legends[0].get_title().get_text()


def test_the_pr_band_figure_says_what_its_band_is_whatever_its_title(tmp_path, drawn):
    _, gtm = _circle_case()
    rng = np.random.default_rng(1)
    seeds = [ev.pr_curve(gtm + rng.random(gtm.shape), gtm, 0.3) for _ in range(3)]
    figures.plot_pr_bands(tmp_path / "b", {"L": seeds}, title="E1: precision-recall over seeds (query-to-reference)")
    texts = drawn[0].legends[0].get_title().get_text()
    assert "band: lowest to highest seed" in texts and "mean interpolated precision over seeds" in texts


# --------------------------------------------------------------------------- report sections


def _facts(features: dict[str, dict[str, dict]]) -> dict[str, dict[str, dict]]:
    """The manifest's ``features`` entry for these feature arrays (method -> run -> arrays)."""
    from vitaplace.engine.extension.features import feature_facts

    return {m: {label: feature_facts(f) for label, f in by_label.items()} for m, by_label in features.items()}


@pytest.mark.parametrize(
    "capped_per_run, expected",
    [
        ((10, 10), "every test-time inference of L hit the step cap"),
        ((6, 6), "60 % of the test-time inferences of L hit the step cap"),
        ((10, 0), "50 % of the test-time inferences of L hit the step cap"),
        ((4, 5), None),  # 45 %: under half, no warning
        ((0, 0), None),
    ],
)
def test_the_report_warns_when_most_test_time_inferences_hit_the_cap(tmp_path, capped_per_run, expected):
    from vitaplace.engine.report.learned import _cap_warnings

    def run(capped: int) -> dict:
        stopped = np.ones(10, dtype=bool)
        stopped[:capped] = False
        return {"latent": np.ones((10, 3)), "inference_stopped": stopped, "inference_steps": np.full(10, 7)}

    features = _facts({
        "L": {"E1/query": run(capped_per_run[0]), "E1/reference": run(capped_per_run[1])},
        "H": {"E1/query": {"profile": np.ones((10, 2))}, "E1/reference": {"profile": np.ones((10, 2))}},
    })
    text = " ".join(_cap_warnings(features)).replace("*", "")
    if expected is None:
        assert text == ""
    else:
        assert expected in text and f"({sum(capped_per_run)} of 20 samples)" in text
        assert "of H" not in text


def _recorded(path: Path, n: int = 10, rng=None) -> Path:
    """A recorded run as imported data has it: images, one deflection sample, no contacts."""
    rng = rng or np.random.default_rng(0)
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return write_run(path, Run.from_arrays(
        images=rng.integers(0, 255, (n, 24, 32, 3), dtype=np.uint8), theta=np.zeros((n, 24)),
        xy=rng.normal(0, 0.02, (n, 24, 2)), poses=np.c_[np.cos(t), np.sin(t), t], name=path.stem,
    ))


def test_inputs_name_recorded_files_and_features_that_carried_nothing(tmp_path):
    from vitaplace.engine.data.dataset import open_run, run_facts
    from vitaplace.engine.report.report import _inputs_section

    query = _recorded(tmp_path / "query.h5")
    h = {"profile": np.ones((10, 4, 4)), "pfh": np.zeros((10, 8)), "sda": np.zeros((10, 24))}
    latent = {"latent": np.ones((10, 3)), "diverged": np.zeros(10, dtype=bool), "inference_steps": np.zeros(10)}
    manifest = {
        "recorded": {"E1/query": str(query)}, "runs": {"E1/query": run_facts(open_run(query))},
        "features": _facts({"H": {"E1/query": h, "E1/reference": {**h, "pfh": np.ones((10, 8))}},
                            "L": {"E1/query": latent, "E1/reference": latent}}),
    }
    text = "\n".join(_inputs_section(manifest))
    assert f"`E1/query` read from `{query}`: 10 samples, no whisker contacts, 1 deflection sample(s)" in text
    assert "**H** on `E1/query`: features `pfh`, `sda` are all zero" in text and "on `profile` alone" in text
    assert "**H** on `E1/reference`: features `sda` are all zero" in text
    assert "**L**" not in text  # its per-sample records (diverged, step counts) are no features


def test_git_dirty_tells_a_changed_checkout_from_a_clean_one(tmp_path):
    from vitaplace.engine.pipeline.provenance import git_dirty

    assert git_dirty(tmp_path) is None  # no checkout
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-C", str(tmp_path)]
    subprocess.run([*git, "init", "-q"], check=True)
    (tmp_path / "a.txt").write_text("1")
    subprocess.run([*git, "add", "a.txt"], check=True)
    subprocess.run([*git, "commit", "-qm", "a"], check=True)
    assert git_dirty(tmp_path) is False
    (tmp_path / "new.txt").write_text("untracked files do not count")
    assert git_dirty(tmp_path) is False
    (tmp_path / "a.txt").write_text("2")
    assert git_dirty(tmp_path) is True


def _recorded_scenario(tmp_path: Path) -> tuple[Path, dict[str, Path]]:
    """A scenario of three recorded runs (12 samples each, no contacts) and method H alone."""
    rng = np.random.default_rng(2)
    files = {name: _recorded(tmp_path / f"{name}.h5", 12, rng) for name in ("train", "query", "reference")}
    scenario = {
        "name": "recorded", "train": {"dataset": str(files["train"])},
        "evaluations": [{"name": "E1",
                         "datasets": {"query": str(files["query"]), "reference": str(files["reference"])}}],
        "methods": [{"name": "H", "plugin": "handcrafted", "params": {"grid": [4, 8]}}], "scoring": {"tau": 0.5},
    }
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(scenario))
    return path, files


def test_recorded_run_report_and_manifest_end_to_end(tmp_path):
    """A scenario on recorded files (no contacts, as imported data): the report defines AUC,
    names the files and says H matched on vision alone; the manifest names the plugins'
    distributions and the dirty flag."""
    from vitaplace.engine.cli.main import main

    path, files = _recorded_scenario(tmp_path)
    assert main(["-q", "run", str(path), "--out", str(tmp_path / "out"), "--no-progress"]) == 0
    report = (tmp_path / "out" / "report.md").read_text()
    assert "AUC is the step-wise average precision" in report
    for name in ("query", "reference"):
        assert f"`E1/{name}` read from `{files[name]}`" in report
        assert f"**H** on `E1/{name}`: features `pfh`, `sda` are all zero" in report
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert manifest["plugins"]["handcrafted"] == {
        "plugin": "handcrafted (vitaplace)", "distribution": "vitaplace", "version": version("vitaplace")}
    assert manifest["git_dirty"] in (True, False)


# --------------------------------------------------------------------------- which figures


@pytest.fixture(scope="module")
def recorded_out(tmp_path_factory) -> Path:
    """The output folder of `_recorded_scenario` (H on E1), with a training curve for H as a
    method that trains records one."""
    from vitaplace.engine.cli.main import main
    from vitaplace.engine.outputs.outdir import training_path

    folder = tmp_path_factory.mktemp("recorded")
    path, _ = _recorded_scenario(folder)
    assert main(["-q", "run", str(path), "--out", str(folder / "out"), "--no-progress"]) == 0
    training_path(folder / "out", "H").parent.mkdir(exist_ok=True)
    training_path(folder / "out", "H").write_text(json.dumps({"layer 1": [3.0, 2.0, 1.5]}))
    return folder / "out"


def _with_report_settings(out: Path, to: Path, settings: dict | None) -> Path:
    """``out`` copied to ``to`` without its report and figures, its resolved scenario's ``report`` ``settings``."""
    copy = Path(shutil.copytree(out, to, ignore=shutil.ignore_patterns("cache", "figures", "report.md*")))
    resolved = yaml.safe_load((copy / "scenario.resolved.yaml").read_text())
    (copy / "scenario.resolved.yaml").write_text(yaml.safe_dump({**resolved, "report": settings}))
    return copy


#: the figures of `recorded_out` that ``report.figures: summary`` draws
SUMMARY_FIGURES = ["pr-E1", "training-H"]
#: and those ``all`` draws besides
PAIR_FIGURES = ["matrices-E1-H-query-to-reference", "trajectories-E1-H-query-to-reference"]


@pytest.mark.parametrize("figures, stems, pdf", [
    (figures, stems, pdf)
    for figures, stems in (("all", SUMMARY_FIGURES + PAIR_FIGURES), ("summary", SUMMARY_FIGURES), ("none", []))
    for pdf in (False, True) if not (figures == "none" and pdf)])  # pdf without figures is refused
def test_each_report_setting_draws_its_figures_and_links_only_those(recorded_out, tmp_path, figures, stems, pdf):
    """``report: {figures, pdf}`` in the folder's resolved scenario: exactly the figures asked
    for, as PNG (and PDF when asked), and report.md shows exactly those PNGs."""
    from vitaplace.engine.report.report import write_report

    copy = _with_report_settings(recorded_out, tmp_path / "copy", {"figures": figures, "pdf": pdf})
    write_report(copy)
    drawn = sorted(p.name for p in (copy / "figures").iterdir()) if (copy / "figures").is_dir() else []
    assert drawn == sorted(f"{stem}.{ext}" for stem in stems for ext in (("png", "pdf") if pdf else ("png",)))
    report = (copy / "report.md").read_text()
    assert sorted(re.findall(r"\]\(figures/([^)]+)\)", report)) == sorted(f"{stem}.png" for stem in stems)
    assert ("None drawn (the scenario's `report.figures` is `none`)" in report) == (figures == "none")


def test_a_run_draws_every_figure_as_png_alone_unless_told(recorded_out):
    drawn = sorted(p.name for p in (recorded_out / "figures").iterdir())
    assert drawn == sorted(f"{stem}.png" for stem in ["pr-E1", *PAIR_FIGURES])  # H records no training curve


def test_a_report_setting_the_folder_cannot_hold_is_a_user_error(recorded_out, tmp_path):
    from vitaplace.engine.report.report import ReportError, write_report

    copy = _with_report_settings(recorded_out, tmp_path / "copy", {"figures": "some"})
    with pytest.raises(ReportError, match=r"scenario.resolved.yaml: report.figures: Input should be 'all', "):
        write_report(copy)


def test_the_report_key_follows_its_settings(recorded_out):
    """Each of the five report settings has its own key (pdf without figures is refused); the
    defaults written out, the key of none."""
    from vitaplace.engine.config.scenario import Scenario
    from vitaplace.engine.pipeline.keys import report_key
    from vitaplace.engine.report.report import report_key_inputs

    inputs = report_key_inputs(recorded_out)
    base = yaml.safe_load((recorded_out / "scenario.resolved.yaml").read_text())
    keys = {(f, pdf): report_key(Scenario.model_validate({**base, "report": {"figures": f, "pdf": pdf}}), inputs)
            for f in ("all", "summary", "none") for pdf in (False, True) if not (f == "none" and pdf)}
    assert len(set(keys.values())) == 5
    assert report_key(Scenario.model_validate(base), inputs) == keys[("all", False)]


# --------------------------------------------------------------------------- experiment tracking


def _fake_mlflow(monkeypatch, client: type) -> list:
    """``mlflow`` and ``mlflow.tracking`` as stand-in modules whose ``MlflowClient`` is
    ``client``; returns the list that records each client made."""
    made: list = []
    module, tracking = ModuleType("mlflow"), ModuleType("mlflow.tracking")

    def make(*args, **kwargs):
        made.append((args, kwargs))
        return client()

    tracking.MlflowClient = make
    module.tracking = tracking
    monkeypatch.setitem(sys.modules, "mlflow", module)
    monkeypatch.setitem(sys.modules, "mlflow.tracking", tracking)
    return made


class _Unreachable:
    def __init__(self):
        raise ConnectionError("tracking server down")


def test_tracking_is_off_unless_asked_and_never_fails_a_run(tmp_path, monkeypatch, caplog):
    """What the real client logs is tested in tests/study/test_mlflow.py (with the `mlflow` extra)."""
    from vitaplace.engine.cli.main import main

    made = _fake_mlflow(monkeypatch, _Unreachable)
    monkeypatch.delenv("VITAPLACE_MLFLOW", raising=False)
    path, _ = _recorded_scenario(tmp_path)
    assert main(["-q", "run", str(path), "--out", str(tmp_path / "out"), "--no-progress"]) == 0
    assert made == []  # never asked for a client
    monkeypatch.setenv("VITAPLACE_MLFLOW", "x")
    assert main(["-q", "run", str(path), "--out", str(tmp_path / "out"), "--no-progress"]) == 0
    assert len(made) == 1
    # the tracker opens its run when the run starts: a client that cannot be made is one warning, the run goes on
    assert ("plugin 'mlflow (vitaplace)': its run-started hook raised ConnectionError: tracking server down"
            in caplog.text)
    monkeypatch.setitem(sys.modules, "mlflow", None)  # not installed: import fails
    assert main(["-q", "run", str(path), "--out", str(tmp_path / "out"), "--no-progress"]) == 0
    assert 'VITAPLACE_MLFLOW=x but MLflow is not installed (pip install "vitaplace[mlflow]"): not logged' in caplog.text


def test_the_difficulty_table_shows_the_touch_pairs_and_older_rows_without_them():
    from vitaplace.engine.outputs.rows import parse_row
    from vitaplace.engine.report.report import difficulty_table

    old = {"nearest_ref_median_m": 0.1, "nearest_ref_p90_m": 0.2, "nearest_ref_heading_median_deg": 5.0,
           "chance_r1": 0.1, "query_touch_share": 0.5, "reference_touch_share": 0.25}  # a run of an older version
    new = {**old, "query_longest_stay_share": 0.1, "reference_longest_stay_share": 0.2, "touch_both_share": 0.125,
           "touch_one_side_share": 0.5, "touch_correspondence": None}
    scores = {"method": "L", "n_queries": 4, "n_revisit": 2, "tau": 0.3, "max_f1": 0.5, "auc": 0.5}
    rows = [parse_row({"environment": "E1", "direction": "query-to-reference", **scores, "difficulty": old}, "E1"),
            parse_row({"environment": "E2", "direction": "query-to-reference", **scores, "difficulty": new}, "E2")]
    lines = difficulty_table(rows).splitlines()
    assert lines[0].endswith("| touch both sides % | touch one side % | touch correspondence % |")
    assert lines[2].endswith("| – | – | – | – | – |")  # longest stays and touch pairs: not measured then
    assert lines[3].endswith("| 10.00 | 20.00 | 12.50 | 50.00 | – |")


def test_the_complementarity_table_and_its_absence_in_older_folders(tmp_path):
    from vitaplace.engine.report.report import _complementarity_section

    assert _complementarity_section(tmp_path) == []  # an older run's folder: no complementarity.json
    (tmp_path / "complementarity.json").write_text("[]")
    assert _complementarity_section(tmp_path) == []  # no vision-only / touch-only pair ran
    record = {"environment": "E1", "direction": "query-to-reference", "vision": "H-V", "touch": "H-T",
              "n_revisit": 4, "vision_r1": 0.5, "touch_r1": 0.25, "vision_wrong": 2, "rescued": 1, "rescue": 0.5,
              "oracle_r1": 0.75}
    (tmp_path / "complementarity.json").write_text(json.dumps([record, {**record, "vision_wrong": 0, "rescued": 0,
                                                                         "rescue": None}]))
    section = _complementarity_section(tmp_path)
    assert section[0] == "## Complementarity"
    table = section[4].splitlines()
    assert table[2] == "| E1 | query-to-reference | H-V | H-T | 4 | 50.00 | 25.00 | 2 | 1 | 50.00 | 75.00 |"
    assert table[3] == "| E1 | query-to-reference | H-V | H-T | 4 | 50.00 | 25.00 | 0 | 0 | – | 75.00 |"


def test_the_results_table_shows_the_tied_share_and_warns_from_a_tenth():
    from vitaplace.engine.outputs.rows import parse_row
    from vitaplace.engine.report.report import results_table

    base = {"environment": "E1", "direction": "query-to-reference", "n_queries": 4, "n_revisit": 3, "tau": 0.3,
            "max_f1": 0.5, "auc": 0.25}
    rows = [parse_row({**base, "method": name, **extra}, "row") for name, extra in
            (("H-T", {"tied_share": 0.76}), ("H-V", {"tied_share": 0.0999}), ("old", {}))]
    lines = results_table(rows).splitlines()
    assert lines[0].endswith("| tied best % |")
    assert [line.rsplit(" | ", 1)[1] for line in lines[2:5]] == ["76.00 |", "9.99 |", "– |"]
    assert lines[5:] == ["", "- WARNING H-T in E1 (query-to-reference): the best match of 76.00 % of the queries is "
                         "tied, so its scores count those queries by the tie rule (correct in proportion), not by a "
                         "match it found"]


@pytest.mark.parametrize("figures, said", [("all", " and its figures"), ("summary", " and its summary figures"),
                                           ("none", "")])
def test_vitaplace_report_says_which_figures_it_drew(tmp_path, figures, said, capsys):
    from vitaplace.engine.cli.main import main

    path, _ = _recorded_scenario(tmp_path)
    out = tmp_path / "out"
    assert main(["-q", "run", str(path), "--out", str(out), "--no-progress", "--set", f"report.figures={figures}"]) == 0
    capsys.readouterr()
    assert main(["-q", "report", str(out)]) == 0
    assert capsys.readouterr().out == f"wrote {out / 'report.md'}{said}\n"
