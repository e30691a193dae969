"""Vision's share of the drive on MuPNet's joint latent, recorded per sample by the plugin's
``transform`` (``drive_visual_share``, ``drive_measured``), summed up per run by
`feature_facts` and tabulated by the report.

Expectations come from the minimiser of a linear network's energy solved in closed form, from
the share written out in numpy on re-inferred latents, and from numbers worked by hand.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import yaml

os.environ.setdefault("MUJOCO_GL", "egl")

from vitaplace.engine.cli.main import main  # noqa: E402
from vitaplace.engine.data.dataset import Run, open_run, write_run  # noqa: E402
from vitaplace.engine.extension.features import feature_facts  # noqa: E402
from vitaplace.engine.report.learned import drive_table  # noqa: E402
from vitaplace.plugins.mupnet.extractor import MupnetExtractor  # noqa: E402

#: both stacks one unit, joint one unit, linear: the energy is a quadratic in three latents
LINEAR = {"image_size": (1, 1), "visual_layers": [1], "tactile_layers": [1], "joint_size": 1, "activation": "linear",
          "epochs": 1, "batch_size": 4, "inference_steps": 2, "backend": "numpy", "seed": 0, "latent_prior": 0.5,
          "threshold_visual": 0.0, "threshold_tactile": 0.0, "threshold_joint": 0.0, "max_steps": 4000}
#: hand-set weights: each upper node predicts its lower one as (upper value) x W
WEIGHTS = {"visual.1": np.array([[0.5, -0.3, 0.8]]), "tactile.1": np.array([[0.4, 0.6, -0.2]]),
           "joint.visual": np.array([[1.5]]), "joint.tactile": np.array([[-0.7]])}


def one_whisker_run(n: int, seed: int) -> Run:
    rng = np.random.default_rng(seed)
    return Run.from_arrays(images=rng.integers(0, 256, (n, 1, 1, 3), dtype=np.uint8), theta=rng.normal(0, 0.3, (n, 1)),
                           xy=rng.normal(0, 0.05, (n, 1, 2)), poses=np.zeros((n, 3)), name=f"r{seed}")


def settled_share(x_v: np.ndarray, x_t: np.ndarray, prior: float) -> float:
    """Vision's share at the minimiser of F = ||x_v - y_v w_v||^2 + (y_v - a y)^2 + ||x_t - y_t w_t||^2
    + (y_t - b y)^2 + prior / 2 (y_v^2 + y_t^2 + y^2) over (y_v, y_t, y): dF = 0 is the linear system
    below (each row half the gradient); then T_v = -2 a (y_v - a y), T_t = -2 b (y_t - b y)."""
    w_v, w_t = WEIGHTS["visual.1"][0], WEIGHTS["tactile.1"][0]
    a, b, h = WEIGHTS["joint.visual"][0, 0], WEIGHTS["joint.tactile"][0, 0], prior / 2
    system = np.array([[w_v @ w_v + 1 + h, 0, -a],
                       [0, w_t @ w_t + 1 + h, -b],
                       [-a, -b, a * a + b * b + h]])
    y_v, y_t, y = np.linalg.solve(system, [w_v @ x_v, w_t @ x_t, 0.0])
    t_v, t_t = abs(a * (y_v - a * y)), abs(b * (y_t - b * y))
    return t_v / (t_v + t_t)


def test_the_share_at_the_settled_point_of_a_linear_network_and_none_without_a_modality():
    extractor = MupnetExtractor(LINEAR)
    extractor.progress = False
    extractor.fit(one_whisker_run(8, 1))
    assert extractor.network is not None
    extractor.network.set_weights(WEIGHTS)
    run = one_whisker_run(5, 2)
    run.missing = {"camera": np.array([False, True, False, False, False])}  # sample 1: touch alone
    inputs = extractor.scaled_inputs(run)
    features = extractor.transform(run)
    expected = [settled_share(inputs["visual"][i], inputs["tactile"][i], 0.5) for i in range(5)]
    assert features["drive_measured"].tolist() == [True, False, True, True, True]
    np.testing.assert_allclose(features["drive_visual_share"][[0, 2, 3, 4]], np.array(expected)[[0, 2, 3, 4]],
                               rtol=1e-4)
    assert features["drive_visual_share"][1] == 0  # not measured: finite, left out of the facts
    facts = feature_facts(features)["drive"]
    measured = np.array(expected)[[0, 2, 3, 4]]
    assert facts["samples"] == 4
    np.testing.assert_allclose([facts["p10"], facts["median"], facts["p90"]],
                               np.percentile(measured, [10, 50, 90]), rtol=1e-4)


def test_a_network_fed_one_modality_records_no_share():
    extractor = MupnetExtractor({**LINEAR, "modalities": ["tactile"]})
    extractor.progress = False
    extractor.fit(one_whisker_run(8, 1))
    features = extractor.transform(one_whisker_run(3, 2))
    assert "drive_visual_share" not in features and "drive" not in feature_facts(features)


def test_the_facts_and_the_table_of_hand_built_shares():
    # shares 0.1, 0.2, ..., 0.5 measured, 0.9 not: numpy's linear percentiles of the five at
    # positions 0.4, 2 and 3.6: 0.1 + 0.4 (0.1) = 0.14, 0.3, 0.4 + 0.6 (0.1) = 0.46
    features = {"latent": np.zeros((6, 2), np.float32),
                "drive_visual_share": np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.9], np.float32),
                "drive_measured": np.array([1, 1, 1, 1, 1, 0], bool)}
    facts = feature_facts(features)["drive"]
    assert facts["samples"] == 5
    np.testing.assert_allclose([facts["p10"], facts["median"], facts["p90"]], [0.14, 0.3, 0.46], rtol=1e-6)
    none = feature_facts({**features, "drive_measured": np.zeros(6, bool)})["drive"]
    assert none == {"samples": 0, "p10": None, "median": None, "p90": None}
    table = drive_table({"L": {"E1/query": {"drive": facts}, "E1/reference": {"drive": none}}, "H": {"E1/query": {}}})
    assert table.splitlines() == [
        "| method | run | samples with both modalities | vision's share, median | 10-90 % |",
        "|---|---|---|---|---|",
        "| L | E1/query | 5 | 0.300 | 0.140 - 0.460 |",
        "| L | E1/reference | 0 | - | - |",
    ]
    assert drive_table({"H": {"E1/query": {}}}) == ""


# --------------------------------------------------------------------------- a tiny run


def _recorded(path: Path, seed: int, n: int = 12) -> Path:
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return write_run(path, Run.from_arrays(
        images=rng.integers(0, 255, (n, 8, 8, 3), dtype=np.uint8), theta=rng.normal(0, 0.2, (n, 4)),
        xy=rng.normal(0, 0.02, (n, 4, 2)), poses=np.c_[np.cos(t), np.sin(t), t], name=path.stem))


TINY = {"image_size": [2, 2], "visual_layers": [4], "tactile_layers": [4], "joint_size": 3, "epochs": 2,
        "batch_size": 4, "inference_steps": 3, "max_steps": 50, "backend": "numpy", "seed": 0, "latent_prior": 0.5}


def reference_shares(model: Path, run_file: Path) -> np.ndarray:
    """Vision's share per sample of ``run_file``, re-inferred with the fitted model and the
    share written out here: T_m = -2 (phi'(A) * E) W^T, A = Y_joint W, E = Y_m - phi(A)."""
    extractor = MupnetExtractor.load(model)
    net, p = extractor.network, extractor.params
    assert net is not None
    inputs = extractor.scaled_inputs(open_run(run_file))
    latents = net.infer(inputs, max_steps=p.max_steps, solver=p.solver(), latent_prior=p.latent_prior).latents
    joint = latents["joint"].astype(np.float64)
    norms = {}
    for m in ("visual", "tactile"):
        w = net.weights[f"joint.{m}"].astype(np.float64)
        a = joint @ w
        error = latents[f"{m}.1"] - np.where(a > 0, a, 0.2 * a)
        norms[m] = np.linalg.norm(-2 * (np.where(a > 0, 1, 0.2) * error) @ w.T, axis=1)
    return norms["visual"] / (norms["visual"] + norms["tactile"])


def test_the_report_tabulates_the_share_of_a_tiny_run(tmp_path):
    files = {name: _recorded(tmp_path / f"{name}.h5", k) for k, name in enumerate(("train", "query", "reference"))}
    scenario = {"name": "drive", "train": {"dataset": str(files["train"])},
                "evaluations": [{"name": "E1", "datasets": {"query": str(files["query"]),
                                                            "reference": str(files["reference"])}}],
                "methods": [{"name": "L", "plugin": "mupnet", "params": TINY},
                            {"name": "L-T", "plugin": "mupnet", "params": {**TINY, "modalities": ["tactile"]}}],
                "scoring": {"tau": 0.5}}
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(scenario))
    out = tmp_path / "out"
    assert main(["-q", "run", str(tmp_path / "s.yaml"), "--out", str(out), "--no-progress"]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    model = next(out / r["output"] for r in manifest["stages"] if r["stage"] == "fit" and r["item"] == "L")
    section = (out / "report.md").read_text().split("## Which modality drives the joint latent\n")[1]
    rows = [line for line in section.split("\n## ")[0].splitlines() if line.startswith("| L")]
    expected = []
    for side in ("query", "reference"):
        p10, median, p90 = np.percentile(reference_shares(model, files[side]), [10, 50, 90])
        expected.append(f"| L | E1/{side} | 12 | {median:.3f} | {p10:.3f} - {p90:.3f} |")
    assert rows == expected  # L-T, fed touch alone, has no row
