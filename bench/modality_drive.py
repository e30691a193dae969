#!/usr/bin/env python
"""Which modality drives MuPNet's joint latent (issue 48): per learned method with both
modalities and per evaluation, each modality's share of the joint layer's gradient at the
settled point (`vitaplace.engine.network.drive`).

For a finished run folder (``vitaplace run`` or ``vitaplace train``: its manifest names the
fitted models and the simulated runs in its cache) this loads every ``mupnet`` method fed
both modalities (the plugin's ``load``), re-infers the samples of the training run and of
both drives of every evaluation with the method's own test-time settings (solver, step cap,
latent prior; a query drop-out's samples from the modalities they have, as the plugin does)
- the features keep only the joint latent, and the split needs every layer's - and prints
per run group the median and 10-90 % range of the visual share ``||T_v|| / (||T_v|| +
||T_t||)`` over the samples that have both modalities, with what explains it:

* ``stiff_t``: touch's share of the joint edges' stiffness (the trace of each edge's
  Gauss-Newton Hessian in the joint latent, `JointDrive.stiffness_shares`): its say in where
  the latent settles between the modalities, since at a settled point the pulls balance;
* ``cos``: the cosine between the two terms (-1: they pull against each other);
* ``prior``: ``||lambda Y_joint|| / (||T_v|| + ||T_t||)``; ``resid``: the gradient left
  relative to the drive (about 0 when settled; a leaky-ReLU kink leaves some);
* ``|E_v|``, ``|E_t|``: the joint edges' prediction errors; ``|Y_v|``, ``|Y_t|``: the top
  latent of each stack (what the joint layer predicts); ``mse_v``, ``mse_t``: the mean
  squared error of each modality's input prediction;
* ``in01``: the share of samples whose scaled tactile values all lie in [0, 1] (the training
  range), and ``v|in01``: the median visual share over those samples alone.

``--clip`` clips the scaled tactile inputs to [0, 1] before inference (the plugin has no
such option; an emulation). The "train" row is test-time inference on the training run's
samples (from the latents' start, as an evaluation's), not training's persistent latents.

    python bench/modality_drive.py /tmp/diag/tb0
    python bench/modality_drive.py /tmp/diag/tb0 --clip --json drive.json --per-run
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from vitaplace.engine.data.dataset import open_run
from vitaplace.engine.network.drive import joint_drive
from vitaplace.engine.network.pc import Network
from vitaplace.kernels.reference import predict
from vitaplace.plugins.mupnet.extractor import MupnetExtractor, presence_groups

BOTH = ("visual", "tactile")


def manifest_items(out: Path) -> tuple[dict, dict[str, Path], dict[str, Path]]:
    """The manifest, its simulated runs (label -> file) and fitted models (method -> folder)."""
    manifest = json.loads((out / "manifest.json").read_text())
    runs, models = {}, {}
    for record in manifest["stages"]:
        path = out / record["output"]  # relative to the run folder (older manifests: absolute)
        if record["stage"] == "simulate":
            runs[record["item"]] = path
        elif record["stage"] == "fit":
            models[record["item"]] = path
    return manifest, runs, models


def bimodal_methods(manifest: dict) -> list[str]:
    """The mupnet methods fed both modalities."""
    names = []
    for name, method in manifest["methods"].items():
        params = {**method.get("defaults", {}), **method.get("params", {})}
        if method["plugin"] == "mupnet" and set(BOTH) <= set(params.get("modalities", BOTH)):
            names.append(name)
    return names


def measure(ex: MupnetExtractor, path: Path, missing: dict, clip: bool) -> dict[str, np.ndarray]:
    """Per sample (with both modalities) of the run at ``path``: shares and what explains them."""
    net, p = ex.network, ex.params
    assert net is not None
    run = open_run(path)
    if missing:
        run.missing = {sensor: np.isin(np.arange(len(run)), index) for sensor, index in missing.items()
                       if sensor != "seed"}
    inputs = ex.scaled_inputs(run)
    inside = ((inputs["tactile"] >= 0) & (inputs["tactile"] <= 1)).all(axis=1)
    if clip:
        inputs["tactile"] = np.clip(inputs["tactile"], 0.0, 1.0)
    rows: dict[str, list[np.ndarray]] = {}
    for present, index in presence_groups(run, list(p.modalities)):
        if tuple(present) != BOTH:
            continue  # one modality: its share is 1 by definition
        x = {m: inputs[m][index] for m in present}
        result = net.infer(x, max_steps=p.max_steps, solver=p.solver(), latent_prior=p.latent_prior)
        drive = joint_drive(net, x, result.latents, prior=p.latent_prior)
        norms, shares = drive.norms(), drive.shares()
        top = {m: f"{m}.{len(net.config.modalities[m].layers)}" for m in BOTH}
        values = {
            "visual_share": shares["visual"], "cos": drive.alignment("visual", "tactile"),
            "prior": np.linalg.norm(drive.prior, axis=1) / (norms["visual"] + norms["tactile"]),
            "resid": drive.residual(), "inside": inside[index],
            "stiff_t": drive.stiffness_shares()["tactile"],
            "capped": ~result.settled,
        }
        for m in BOTH:
            values[f"E_{m[0]}"] = np.linalg.norm(drive.errors[m], axis=1)
            values[f"Y_{m[0]}"] = np.linalg.norm(result.latents[top[m]], axis=1)
            values[f"mse_{m[0]}"] = result_mse(net, x, result.latents, m)
        for key, value in values.items():
            rows.setdefault(key, []).append(np.asarray(value))
    return {key: np.concatenate(parts) for key, parts in rows.items()}


def result_mse(net: Network, inputs: dict[str, np.ndarray], latents: dict[str, np.ndarray],
               modality: str) -> np.ndarray:
    """Per sample, the mean squared error of the prediction of ``modality``'s input."""
    w = net.host_weights()[f"{modality}.1"].astype(np.float64)
    _, _, error, _ = predict(latents[f"{modality}.1"].astype(np.float64), w, inputs[modality].astype(np.float64),
                             net.config.activation, net.config.slope)
    return (error**2).mean(axis=1)


def summary(values: dict[str, np.ndarray]) -> dict[str, float]:
    """Medians (and the visual share's 10 / 90 %) of one group of samples."""
    share = values["visual_share"]
    out = {"samples": int(len(share)), "visual_p10": float(np.percentile(share, 10)),
           "visual_median": float(np.median(share)), "visual_p90": float(np.percentile(share, 90)),
           "in01": float(values["inside"].mean()), "capped": int(values["capped"].sum())}
    out["visual_median_in01"] = float(np.median(share[values["inside"]])) if values["inside"].any() else float("nan")
    for key in ("stiff_t", "cos", "prior", "resid", "E_v", "E_t", "Y_v", "Y_t", "mse_v", "mse_t"):
        out[key] = float(np.median(values[key]))
    return out


COLUMNS = ("n", "visual share p10/med/p90", "tactile med", "stiff_t", "cos", "prior", "resid", "|E_v|", "|E_t|",
           "|Y_v|", "|Y_t|", "mse_v", "mse_t", "in01", "v|in01")


def row(label: str, s: dict[str, float]) -> str:
    cells = [str(s["samples"]), f"{s['visual_p10']:.3f} / {s['visual_median']:.3f} / {s['visual_p90']:.3f}",
             f"{1 - s['visual_median']:.3f}", f"{s['stiff_t']:.3f}", f"{s['cos']:+.2f}", f"{s['prior']:.2f}",
             f"{s['resid']:.1e}"]
    cells += [f"{s[k]:.3g}" for k in ("E_v", "E_t", "Y_v", "Y_t", "mse_v", "mse_t")]
    cells += [f"{s['in01']:.2f}", f"{s['visual_median_in01']:.3f}"]
    return f"| {label} | " + " | ".join(cells) + " |"


def parse(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0],
                                     formatter_class=argparse.RawTextHelpFormatter)
    parser.add_argument("out", type=Path, help="a finished run folder (its manifest.json and cache)")
    parser.add_argument("--method", action="append", help="only these methods (default: every bimodal mupnet one)")
    parser.add_argument("--clip", action="store_true", help="clip the scaled tactile inputs to [0, 1] first")
    parser.add_argument("--per-run", action="store_true", help="a row per drive, not per evaluation")
    parser.add_argument("--json", type=Path, help="write the summaries here")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse(argv)
    try:
        manifest, runs, models = manifest_items(args.out)
    except (OSError, KeyError, json.JSONDecodeError) as exc:
        print(f"{args.out}: not a finished run folder ({exc})", file=sys.stderr)
        return 2
    methods = args.method or bimodal_methods(manifest)
    report: dict[str, dict[str, dict[str, float]]] = {}
    for name in methods:
        ex = MupnetExtractor.load(models[name])
        ex.progress = False
        start = time.perf_counter()
        per_run = {label: measure(ex, path, manifest.get("dropout", {}).get(label, {}), args.clip)
                   for label, path in runs.items()}
        groups: dict[str, list[str]] = {}
        for label in per_run:
            groups.setdefault(label if args.per_run else label.split("/")[0], []).append(label)
        report[name] = {group: summary({k: np.concatenate([per_run[lb][k] for lb in labels])
                                        for k in per_run[labels[0]]})
                        for group, labels in groups.items()}
        report[f"{name}/runs"] = {label: summary(values) for label, values in per_run.items()}
        print(f"\n{name}{' (tactile clipped to [0, 1])' if args.clip else ''}: "
              f"{sum(len(v['visual_share']) for v in per_run.values())} samples in {time.perf_counter() - start:.0f} s")
        print("| run | " + " | ".join(COLUMNS) + " |")
        print("|" + "---|" * (len(COLUMNS) + 1))
        for group, s in report[name].items():
            print(row(group, s))
    if args.json:
        args.json.write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
