"""Figures for the evaluation: matrices with decisions (paper Fig. 4), PR curves
(paper Fig. 5), trajectories over the arena map, training energy.

Every function draws on its own ``matplotlib.figure.Figure`` with an Agg canvas (no pyplot,
no global backend switch), saves ``<out_stem>.<format>`` atomically for each of its
``formats`` (PNG and PDF unless told) and returns the paths. Legends sit outside the axes
(they never hide data) and colour bars name the quantity they show.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Circle, Patch, Polygon, Rectangle
from numpy.typing import ArrayLike

from vitaplace.engine.base.atomic import atomic_path
from vitaplace.engine.evaluation.evaluate import Decisions, PRCurve
from vitaplace.engine.outputs.outdir import PR_CURVE, evaluation_dir

__all__ = ["plot_energy", "plot_matrices", "plot_pr_curves", "plot_trajectories", "OUTCOME_COLOURS"]

OUTCOME_COLOURS = {"TP": "tab:green", "FP": "tab:red", "TP|FP": "tab:olive", "FN": "tab:orange", "TN": "tab:grey"}
#: percentiles of the feature distances that span the TME colour scale: a few far-off samples
#: (e.g. touch outliers) would otherwise stretch it until the matches are all one colour
TME_PERCENTILES = (1.0, 90.0)
#: finite distances beyond this in size (or under its inverse) are drawn scaled to the largest,
#: so that the colour scale's arithmetic cannot overflow (the contract allows any finite value)
TME_SCALED = 1e100
#: line style per curve of a PR figure (curves drawn later are thinner and on top, so a
#: curve that another one covers still shows around it)
PR_STYLES = ("-", "--", ":", "-.")
#: the widest and the thinnest PR curve, in points, however many curves a figure holds
PR_LINEWIDTHS = (3.0, 1.0)
#: a PR figure's axes (width, height) in inches; its legend of one line per curve sits to the
#: right of them, the figure as wide as its longest line needs (a handle, then characters of
#: the legend's small font) and as tall as its lines need
PR_AXES_SIZE = (5.5, 4.5)
PR_LEGEND_HANDLE = 1.0
PR_LEGEND_CHARACTER = 0.07
PR_LEGEND_LINE = 0.19
#: what the lines and bands of `plot_pr_bands` show (written into the figure)
#: the formats a figure is saved in unless told (a run's report: `ReportSettings.pdf`)
FORMATS = ("png", "pdf")
#: the metadata each format is saved with (none that changes between runs)
_METADATA: dict[str, dict[str, None]] = {"png": {"Software": None},
                                         "pdf": {"CreationDate": None, "Creator": None, "Producer": None}}
BAND_NOTE = ("line: mean interpolated precision over seeds; band: lowest to highest seed\n"
             "(interpolated precision: the best precision at that recall or above)")


def _new_figure(figsize: tuple[float, float]) -> Figure:
    fig = Figure(figsize=figsize, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Figure, out_stem: str | os.PathLike, formats: Sequence[str] = FORMATS) -> list[Path]:
    stem = Path(out_stem)
    paths = []
    for fmt in formats:
        path = stem.with_name(stem.name + "." + fmt)
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format=fmt, dpi=150, metadata=_METADATA[fmt])
        paths.append(path)
    return paths


def _primary_outcome(decisions: Decisions) -> np.ndarray:
    """One colour class per query: TP, FP (accepted and wrong, whether or not also FN), TP|FP
    (accepted, tied between true and wrong matches), FN, TN."""
    outcome = decisions.outcome
    return np.where(outcome == "FP+FN", "FP", outcome)


def _tme_colours(tme: np.ndarray) -> tuple[np.ndarray, tuple[float, float], str]:
    """The TME as drawn: its finite values (+inf blank), scaled by the power of two nearest the
    largest of them when that is beyond ``TME_SCALED`` in size or under its inverse (a plugin may
    return distances near the largest float, or subnormal ones, whose colour scale would overflow),
    the `TME_PERCENTILES` of them that span the colours, and the colour bar's label, which gives
    the percentiles and the range in the TME's units. The scaling is `np.ldexp`, exact: a
    division by a subnormal raises a spurious overflow on some CPUs' SIMD paths."""
    finite = tme[np.isfinite(tme)]
    largest = float(np.abs(finite).max()) if finite.size else 0.0
    exponent = int(np.frexp(largest)[1]) - 1 if largest and not 1 / TME_SCALED < largest < TME_SCALED else 0
    scale = float(np.ldexp(1.0, exponent))
    shown = np.ldexp(np.where(np.isfinite(tme), tme, np.nan), -exponent)
    if not finite.size:
        return shown, (0.0, 1.0), "feature distance; every pair +inf (none could be compared)"
    low, high = (float(v) for v in np.percentile(np.ldexp(finite, -exponent), TME_PERCENTILES))
    unit = f" / {scale:.3g}" if scale != 1.0 else ""
    return shown, (low, high), (
        f"feature distance{unit}; colours: percentiles {TME_PERCENTILES[0]:g}-{TME_PERCENTILES[1]:g}\n"
        f"= [{low * scale:.3g}, {high * scale:.3g}] "
        f"(finite values {finite.min():.3g}-{finite.max():.3g})")


def plot_matrices(out_stem: str | os.PathLike, tme: ArrayLike, gtm: ArrayLike, decisions: Decisions,
                  title: str = "", formats: Sequence[str] = FORMATS) -> list[Path]:
    """GTM and TME heat maps side by side (rows = queries, columns = references) with the
    decision of each query drawn as a dot at (query, best match): green TP, red FP
    (accepted and wrong), olive TP|FP (accepted, tied between true and wrong matches; drawn at
    the lowest index of the tie), orange FN (rejected although a revisit existed), grey TN.
    The TME colours span the `TME_PERCENTILES` of its values (its colour bar says so); GTM
    cells that are infinite (headings further apart than the tolerance) stay blank."""
    tme = np.asarray(tme, dtype=float)
    gtm = np.asarray(gtm, dtype=float)
    n_q, n_r = tme.shape
    fig = _new_figure((11, 5))
    axes = fig.subplots(1, 2)
    outcome = _primary_outcome(decisions)
    rows = np.arange(n_q)
    size = float(np.clip(2000.0 / max(n_q, 1), 2.0, 30.0))
    shown_tme, tme_range, tme_label = _tme_colours(tme)
    for ax, mat, name, cmap, quantity, limits in (
        (axes[0], gtm, "GTM (ground-truth distance" + ("; blank: facing apart)" if np.isinf(gtm).any() else ")"),
         "viridis", "ground-truth distance [m]", (None, None)),
        (axes[1], shown_tme, "TME (feature distance" + ("; blank: +inf)" if np.isinf(tme).any() else ")"), "magma",
         tme_label, tme_range),
    ):
        shown = np.where(np.isfinite(mat), mat, np.nan)
        im = ax.imshow(shown, cmap=cmap, aspect="auto", interpolation="nearest", origin="upper",
                       vmin=limits[0], vmax=limits[1])
        fig.colorbar(im, ax=ax, shrink=0.85, label=quantity, extend="neither" if limits[0] is None else "both")
        for label, colour in OUTCOME_COLOURS.items():
            sel = outcome == label
            if sel.any():
                ax.scatter(decisions.best_match[sel], rows[sel], s=size, c=colour,
                           edgecolors="white", linewidths=0.3, label=f"{label} ({int(sel.sum())})", zorder=3)
        ax.set_xlim(-0.5, n_r - 0.5)
        ax.set_ylim(n_q - 0.5, -0.5)
        ax.set_xlabel("reference index")
        ax.set_ylabel("query index")
        ax.set_title(name)
    handles = [Line2D([], [], marker="o", linestyle="", color=c, label=f"{k} ({int((outcome == k).sum())})")
               for k, c in OUTCOME_COLOURS.items()]
    fig.legend(handles=handles, loc="outside lower center", ncols=len(handles), fontsize="small",
               title="decision of each query at its best match")
    sup = f"tau={decisions.tau:g}, delta={decisions.delta:g}"
    fig.suptitle(f"{title} ({sup})" if title else sup)
    return _save(fig, out_stem, formats)


def plot_pr_curves(out_stem: str | os.PathLike, curves: Mapping[str, PRCurve], title: str = "",
                   formats: Sequence[str] = FORMATS) -> list[Path]:
    """Precision-recall curve per method with the max-F1 point marked; the legend gives max F1
    and AUC.  Drawn step-wise in threshold order so that the area under the drawn curve is the
    AUC (step-wise average precision)."""
    labels = [f"{name} (max F1={curve.max_f1:.3f}, AUC={curve.auc:.3f})" for name, curve in curves.items()]
    legend_title = "AUC: step-wise average precision"
    fig = _pr_figure(labels, legend_title)
    ax = fig.subplots()
    for i, (label, curve) in enumerate(zip(labels, curves.values(), strict=True)):
        colour = f"C{i % 10}"
        order = np.argsort(curve.deltas, kind="stable")
        ax.plot(curve.recall[order], curve.precision[order], drawstyle="steps-pre", color=colour,
                label=label, **_pr_style(i, len(curves)))
        k = curve.index_at_max_f1
        ax.plot([curve.recall[k]], [curve.precision[k]], marker="*", markersize=12, color=colour,
                markeredgecolor="black", linestyle="", zorder=10 + i)
    _finish_pr_axes(fig, ax, "precision", len(curves), title or "Precision-recall (★ = max F1)", legend_title)
    return _save(fig, out_stem, formats)


def _pr_figure(labels: Sequence[str], legend_title: str) -> Figure:
    """A figure for PR curves with a legend of ``labels`` under ``legend_title``: `PR_AXES_SIZE`
    for the axes and room to their right for the legend, as tall as the taller of the two (a
    legend taller than the figure would be cut off)."""
    width, height = PR_AXES_SIZE
    lines = [*legend_title.splitlines(), *labels]
    legend_width = PR_LEGEND_HANDLE + PR_LEGEND_CHARACTER * max(len(line) for line in lines)
    return _new_figure((width + legend_width, max(height + 1.0, 1.0 + PR_LEGEND_LINE * (len(lines) + 1))))


def _pr_style(i: int, n_curves: int) -> dict:
    """Line style, width and z-order of the ``i``-th of ``n_curves`` PR curves: each curve its
    own dash pattern, the later ones thinner (from the first to the last of `PR_LINEWIDTHS`,
    however many curves) and above, so coinciding stretches (e.g. two methods at precision 1)
    show both curves."""
    widest, thinnest = PR_LINEWIDTHS
    width = widest - (widest - thinnest) * i / (n_curves - 1) if n_curves > 1 else widest
    return {"linestyle": PR_STYLES[i % len(PR_STYLES)], "linewidth": width, "zorder": 2 + i}


def _finish_pr_axes(fig: Figure, ax: Axes, ylabel: str, n_curves: int, title: str, legend_title: str) -> None:
    """Limits, labels, grid, a legend right of the axes (covering no data; one line per curve)
    with ``legend_title`` (what the curves show) and the title."""
    ax.set_xlim(-0.02, 1.02)
    ax.set_ylim(-0.02, 1.05)
    ax.set_xlabel("recall")
    ax.set_ylabel(ylabel)
    ax.grid(True, alpha=0.3)
    if n_curves:
        fig.legend(loc="outside right upper", fontsize="small", title=legend_title, title_fontsize="small")
    ax.set_title(title)


def interpolated_precision(curve: PRCurve, recall_grid: np.ndarray) -> np.ndarray:
    """Precision at each recall of ``recall_grid``: the best precision the curve reaches at
    that recall or above (0 where it never gets there) - the usual interpolated PR curve."""
    order = np.argsort(curve.recall, kind="stable")[::-1]
    best = np.maximum.accumulate(curve.precision[order])  # best precision at recall >= recall[order]
    recall_desc = curve.recall[order]
    idx = np.searchsorted(-recall_desc, -recall_grid, side="right") - 1  # last point with recall >= r
    return np.where(idx >= 0, best[np.clip(idx, 0, None)], 0.0)


def plot_pr_bands(out_stem: str | os.PathLike, curves: Mapping[str, Sequence[PRCurve]], title: str = "") -> list[Path]:
    """Per method, the mean interpolated precision-recall curve over seeds with the band
    from the lowest to the highest seed (the figure says so, whatever the title); the legend
    gives the seeds and max F1 mean +- std."""
    grid = np.linspace(0.0, 1.0, 201)
    f1 = {name: np.array([c.max_f1 for c in seeds]) for name, seeds in curves.items()}
    labels = [f"{name} ({len(f)} seeds, max F1 {f.mean():.3f}{f' ± {f.std(ddof=1):.3f}' if len(f) > 1 else ''})"
              for name, f in f1.items()]
    fig = _pr_figure(labels, BAND_NOTE)
    ax = fig.subplots()
    for i, (label, seeds) in enumerate(zip(labels, curves.values(), strict=True)):
        colour = f"C{i % 10}"
        prec = np.array([interpolated_precision(c, grid) for c in seeds])
        ax.plot(grid, prec.mean(axis=0), color=colour, label=label, **_pr_style(i, len(curves)))
        ax.fill_between(grid, prec.min(axis=0), prec.max(axis=0), color=colour, alpha=0.2, linewidth=0)
    _finish_pr_axes(fig, ax, "interpolated precision", len(curves), title or "Precision-recall over seeds", BAND_NOTE)
    return _save(fig, out_stem)



def write_pr_bands(out: Path, folders: Mapping[int, Path], rows: Sequence[Mapping]) -> list[Path]:
    """``pr-bands-<environment>-<direction>`` figures in ``out`` from the seed run folders'
    saved curves (``evaluations/ENV/METHOD/DIRECTION/pr_curve.npz``)."""
    from vitaplace.engine.evaluation.pairfiles import load_curve

    groups: dict[tuple[str, str], dict[str, list[PRCurve]]] = {}
    for row in sorted(rows, key=lambda r: r["seed"]):
        path = evaluation_dir(folders[row["seed"]], row["environment"], row["method"], row["direction"]) / PR_CURVE
        if path.is_file():
            by_method = groups.setdefault((row["environment"], row["direction"]), {})
            by_method.setdefault(row["method"], []).append(load_curve(path))
    written = []
    for (env, direction), curves in groups.items():
        written += plot_pr_bands(Path(out) / f"pr-bands-{env}-{direction}", curves,
                                 f"{env}: precision-recall over seeds ({direction})")
    return written


def _arena_bounds(arena: Mapping) -> tuple[float, float, float, float] | None:
    """(xmin, xmax, ymin, ymax) of an arena ``width`` x ``depth`` centred on the origin."""
    if "width" not in arena or "depth" not in arena:
        return None
    hx, hy = float(arena["width"]) / 2.0, float(arena["depth"]) / 2.0
    return -hx, hx, -hy, hy


def _landmark_patch(lm: Mapping) -> Patch:
    """Patch for a landmark of `EnvironmentSpec.top_view`: 'box' (size [sx, sy], yaw in degrees),
    'cylinder' (radius), 'rock' (polygon [[x, y], ...] in the world frame)."""
    kind = lm.get("type", "box")
    x, y = (float(v) for v in lm["pos"][:2])
    colour = tuple(float(c) for c in lm.get("rgba", (0.55, 0.55, 0.55, 1.0)))[:3]
    style = dict(facecolor=colour, edgecolor="black", alpha=0.6, zorder=1)
    if kind == "cylinder":
        return Circle((x, y), float(lm["radius"]), **style)
    if kind == "rock" and "polygon" in lm:
        return Polygon(np.asarray(lm["polygon"], dtype=float)[:, :2], closed=True, **style)
    sx, sy = (float(v) for v in lm["size"][:2])
    return Rectangle((x - sx / 2, y - sy / 2), sx, sy, angle=float(lm.get("yaw", 0.0)), rotation_point="center",
                     **style)


def plot_trajectories(out_stem: str | os.PathLike, query_poses: ArrayLike, reference_poses: ArrayLike,
                      decisions: Decisions, arena: Mapping | None = None, title: str = "",
                      formats: Sequence[str] = FORMATS) -> list[Path]:
    """Top view of the query and reference runs over the arena, with accepted matches drawn
    as segments from query pose to matched reference pose (green TP, red FP, olive TP|FP: a
    tie between true and wrong matches, drawn to its lowest index)."""
    q = np.asarray(query_poses, dtype=float)[:, :2]
    r = np.asarray(reference_poses, dtype=float)[:, :2]
    fig = _new_figure((6.5, 6.5))
    ax = fig.subplots()
    if arena:
        bounds = _arena_bounds(arena)
        if bounds is not None:
            x0, x1, y0, y1 = bounds
            ax.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, edgecolor="black", linewidth=2, zorder=1))
        for lm in arena.get("landmarks", []) or []:
            ax.add_patch(_landmark_patch(lm))
    ax.plot(r[:, 0], r[:, 1], "-", color="tab:blue", lw=1.2, label="reference run", zorder=2)
    ax.plot(q[:, 0], q[:, 1], "-", color="tab:purple", lw=1.2, label="query run", zorder=2)
    bm, outcome = decisions.best_match, _primary_outcome(decisions)
    for kind in ("TP", "FP", "TP|FP"):
        idx, colour, label = np.flatnonzero(outcome == kind), OUTCOME_COLOURS[kind], f"{kind} match"
        if idx.size:
            segs = np.stack([q[idx], r[bm[idx]]], axis=1)
            ax.add_collection(LineCollection(list(segs), colors=colour, linewidths=0.8, alpha=0.8, zorder=3,
                                             label=f"{label} ({idx.size})"))
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    fig.legend(loc="outside lower center", ncols=2, fontsize="small")
    ax.set_title(title or "Trajectories and accepted matches")
    return _save(fig, out_stem, formats)


def plot_energy(out_stem: str | os.PathLike, energy: Mapping[str, Sequence[float]], title: str = "",
                formats: Sequence[str] = FORMATS) -> list[Path]:
    """Training energy per layer (one line per key) against epoch, log y axis
    (non-positive values are masked)."""
    fig = _new_figure((6.5, 4.5))
    ax = fig.subplots()
    plotted = False
    for name, values in energy.items():
        v = np.asarray(values, dtype=float)
        if v.size == 0:
            continue
        v = np.where(v > 0, v, np.nan)
        ax.plot(np.arange(1, v.size + 1), v, marker="o" if v.size < 30 else None, markersize=3, label=str(name))
        plotted = True
    if plotted and np.any([np.any(np.asarray(v, dtype=float) > 0) for v in energy.values() if len(v)]):
        ax.set_yscale("log")
        fig.legend(loc="outside right upper", fontsize="small", title="layer")
    else:
        ax.text(0.5, 0.5, "no positive energy values", transform=ax.transAxes, ha="center", va="center")
    ax.set_xlabel("epoch")
    ax.set_ylabel("energy")
    ax.grid(True, which="both", alpha=0.3)
    ax.set_title(title or "Training energy per layer")
    return _save(fig, out_stem, formats)
