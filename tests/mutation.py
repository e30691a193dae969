#!/usr/bin/env python
"""Mutation testing on demand (not part of CI): does the suite notice when the code is wrong?

Each mutant changes one line of the package the way a real bug would (a sign, an index,
an off-by-one, a swapped argument, a skipped step). The script applies it, runs the tests
that guard that code, and restores the file; a mutant is *killed* when a test fails. The
kill rate is over the mutants that change behaviour; `EQUIVALENT` lists mutants kept for
the record that cannot change any result, with the reason.

    python tests/mutation.py              # all mutants (a few minutes on 2 cores)
    python tests/mutation.py pc kernels   # only mutants whose name starts with these
    python tests/mutation.py --list

Exit status 0 when the kill rate is at least 90 %.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET = 0.90


@dataclass(frozen=True)
class Mutant:
    name: str
    path: str
    old: str
    new: str
    tests: tuple[str, ...]


def m(name: str, path: str, old: str, new: str, *tests: str) -> Mutant:
    return Mutant(name, path, old, new, tests)


PC = ("tests/test_pc.py",)
KERNELS = ("tests/test_kernels.py",)
EVAL = ("tests/test_evaluate.py",)
HAND = ("tests/test_handcrafted.py",)
SIM = ("tests/test_sim.py",)
WORLDS = ("tests/test_worlds.py",)
CLI = ("tests/test_cli.py",)
MUPNET = ("tests/test_mupnet_plugin.py",)
SWEEP = ("tests/test_sweep.py",)
MATIMPORT = ("tests/test_matimport.py",)

PFH_NORMALISE = "    return (counts * (100.0 / counts.sum())).astype(np.float32)"

MUTANTS = [
    # --- the predictive-coding network and its backends
    m("pc: one sample per minibatch never trained", "engine/pc.py",
      "index = np.sort(order[b * cfg.batch_size : (b + 1) * cfg.batch_size])",
      "index = np.sort(order[b * cfg.batch_size : (b + 1) * cfg.batch_size - 1])", *PC),
    m("pc: latents not written back to the store", "engine/pc.py",
      "            self.be.scatter_rows(y, self.index, latents[node])", "            pass", *PC),
    m("pc: latent init 0.1 -> 0", "engine/pc.py", "LATENT_INIT = 0.1", "LATENT_INIT = 0.0", *PC),
    m("pc: per-sample limit not scaled by the layer width", "engine/pc.py",
      "be.upload(threshold * width, state.limits)", "be.upload(threshold, state.limits)", *PC),
    m("pc: inference step cap off by one", "engine/pc.py",
      "todo = min(self.STEPS_PER_CHECK, max_steps - done)", "todo = min(self.STEPS_PER_CHECK, max_steps - done + 1)", *PC),
    m("pc: energy history not divided by the samples", "engine/pc.py",
      "history.energy[name].append(total / n)", "history.energy[name].append(total)", *PC),
    m("pc: Glorot limit uses fan_in only", "engine/pc.py",
      "limit = math.sqrt(6.0 / (fan_in + fan_out))", "limit = math.sqrt(6.0 / fan_in)", *PC),
    m("numpy backend: weight update skips the last partial chunk", "engine/backends.py",
      "        for i in range(0, n_l, step):", "        for i in range(0, n_l - n_l % step if n_l > step else n_l, step):", *PC),
    m("numpy backend: top-down error added instead of subtracted", "engine/backends.py",
      "            np.subtract(t, E_above, out=t)", "            np.add(t, E_above, out=t)", *PC),
    m("numpy backend: inference mask ignored", "engine/backends.py",
      "            np.multiply(t, mask[:, None], out=t)", "            pass", *PC),
    m("numpy backend: leaky slope ignored", "engine/backends.py",
      "            np.maximum(G, self.dtype.type(slope), out=G)  # G = phi'(A)",
      "            np.maximum(G, self.dtype.type(0.0), out=G)  # G = phi'(A)", *PC),
    m("numpy backend: a stopped sample keeps counting steps", "engine/backends.py",
      "        active &= ~done\n        steps += active", "        steps += active\n        active &= ~done", *PC),
    # --- the Warp kernels
    m("kernels: stop test <= instead of <", "kernels/warp_kernels.py",
      "if not (row_energy[e, r] < limits[e]):", "if not (row_energy[e, r] <= limits[e]):", *KERNELS),
    m("kernels: split-K sum drops the last slice", "kernels/warp_kernels.py",
      "        for s in range(1, D.shape[0]):", "        for s in range(1, D.shape[0] - 1):", *KERNELS),
    m("kernels: latent step ignores the mask", "kernels/warp_kernels.py",
      "            if mask[r] == 0:\n                return", "            if mask[r] == 2:\n                return", *KERNELS),
    m("kernels: gather ignores the index", "kernels/warp_kernels.py",
      "    dst[r, c] = src[index[r], c]", "    dst[r, c] = src[r, c]", *KERNELS),
    m("kernels: weight kernel does not keep W transposed", "kernels/warp_kernels.py",
      "            wp.tile_store(Wt, wp.tile_transpose(w), offset=(col, row))", "            pass", *KERNELS),
    m("kernels: sigmoid padding leaks into the row energies", "kernels/warp_kernels.py",
      '        if wp.static(activation == "sigmoid"):', '        if wp.static(activation == "none"):', *KERNELS),
    m("kernels: latent split uses the wrong K range", "kernels/warp_kernels.py",
      "        for k in range(s * steps, end):", "        for k in range(s * steps + 1, end):", *KERNELS),
    m("kernels: weight step sign", "kernels/warp_kernels.py",
      "        w = wp.tile_load(W, shape=(tm, tn), offset=(row, col)) + d * two_eta",
      "        w = wp.tile_load(W, shape=(tm, tn), offset=(row, col)) - d * two_eta", *KERNELS),
    m("reference: tanh derivative", "kernels/reference.py", "        return one - t * t", "        return one - t", *KERNELS),
    # --- evaluation
    m("evaluate: accept with < instead of <=", "engine/evaluate.py",
      "    accepted = best_tme <= delta", "    accepted = best_tme < delta", *EVAL),
    m("evaluate: precision defined as 0 with nothing accepted", "engine/evaluate.py",
      "    precision = _safe_div(tp, tp + fp, 1.0)", "    precision = _safe_div(tp, tp + fp, 0.0)", *EVAL),
    m("evaluate: recall over queries instead of revisits", "engine/evaluate.py",
      "    recall = _safe_div(tp, np.full_like(tp, n_revisit), 0.0)",
      "    recall = _safe_div(tp, np.full_like(tp, int(tme_a.shape[0])), 0.0)", *EVAL),
    m("evaluate: revisit tolerance exclusive", "engine/evaluate.py",
      "    has_revisit = gtm_a.min(axis=1) <= tau", "    has_revisit = gtm_a.min(axis=1) < tau", *EVAL),
    m("evaluate: ground truth ignores y", "engine/evaluate.py",
      'gtm = cdist(q[:, :2], r[:, :2], metric="euclidean")', 'gtm = cdist(q[:, :1], r[:, :1], metric="euclidean")', *EVAL),
    m("runner: ground truth built reference-to-query", "engine/runner.py",
      'folder, tme, self.open(f"{e.name}/{q}").poses, self.open(f"{e.name}/{r}").poses,',
      'folder, tme, self.open(f"{e.name}/{r}").poses, self.open(f"{e.name}/{q}").poses,', *CLI),
    m("runner: evaluation cache key ignores the settings", "engine/runner.py",
      'key = content_hash("evaluate", STAGE_VERSION["evaluate"], qpath.name, rpath.name, settings.model_dump())',
      'key = content_hash("evaluate", STAGE_VERSION["evaluate"], qpath.name, rpath.name)', *CLI),
    # --- the hand-crafted front end
    m("pfh: upper-edge values beyond the last bin", "plugins/handcrafted/pfh.py",
      "    return np.clip(idx, 0, bins - 1)", "    return np.clip(idx, 0, bins)", *HAND),
    m("pfh: histogram normalised to 1 instead of 100", "plugins/handcrafted/pfh.py",
      PFH_NORMALISE, PFH_NORMALISE.replace("100", "1"), *HAND),
    m("sda: per_axis ignores the threshold", "plugins/handcrafted/sda.py",
      "        positive = d > threshold  # (N, S, W, 2)", "        positive = d > 0  # (N, S, W, 2)", *HAND),
    m("sda: magnitude slope inverted", "plugins/handcrafted/sda.py",
      "        return _slope(delta[..., 1], delta[..., 0]).astype(np.float32)\n    if mode",
      "        return _slope(delta[..., 0], delta[..., 1]).astype(np.float32)\n    if mode", *HAND),
    # --- recorded runs: `vitaplace import` and `dataset:` in scenarios
    m("matimport: v7.3 arrays not transposed back", "engine/matimport.py",
      "        return data.T\n", "        return data\n", *MATIMPORT),
    m("matimport: boards and columns swapped in the whisker index", "engine/matimport.py",
      "theta_run = np.transpose(theta, (2, 1, 0)).reshape(n, 24)",
      "theta_run = np.transpose(theta, (2, 0, 1)).reshape(n, 24)", *MATIMPORT),
    m("matimport: pose_return.mat not looked for", "engine/matimport.py",
      "for f in POSE_FILES if (folder / f).is_file()", "for f in POSE_FILES[:1] if (folder / f).is_file()", *MATIMPORT),
    m("matimport: NaN in theta or xy not named by file and variable", "engine/matimport.py",
      "        raise DatasetError(f\"{path}: variable '{name}' has shape {arr.shape}, expected {_EXPECTED[kind]}\")\n"
      "    _check_finite(arr, path, name)",
      "        raise DatasetError(f\"{path}: variable '{name}' has shape {arr.shape}, expected {_EXPECTED[kind]}\")",
      *MATIMPORT),
    m("runner: a recorded run's key ignores its content", "engine/runner.py",
      'content_hash("recorded", STAGE_VERSION["simulate"], checksum.digest(path))',
      'content_hash("recorded", STAGE_VERSION["simulate"], str(path))', *MATIMPORT),
    m("runner: recorded runs not checked before the stages", "engine/runner.py",
      "        run.validate()\n", "", *MATIMPORT),
    m("scenario: recorded evaluation runs not relative to the scenario file", "engine/scenario.py",
      '            fix(entry.get("datasets"), ("query", "reference"))', "            pass", *MATIMPORT),
    m("features: unusable-data warning repeated for every method", "engine/features.py",
      "    if feature in run.warnings:\n        return\n", "", *MATIMPORT),
    m("handcrafted: no warning for a run without contacts", "plugins/handcrafted/extractor.py",
      "if n and int(run.contact_offsets[-1]) == 0:", "if n and int(run.contact_offsets[-1]) < 0:", *MATIMPORT),
    # --- the simulator
    m("sim: stored xy taken at the start of the cycle", "engine/sim/simulate.py",
      "            xy[k] = series[-1]", "            xy[k] = series[0]", *SIM),
    m("sim: route lateral noise std doubled", "engine/sim/controllers.py",
      "        self._lateral = _OU(self.rng, self.spec.lateral_noise, tau)",
      "        self._lateral = _OU(self.rng, 2 * self.spec.lateral_noise, tau)", *SIM),
    m("sim: OU process variance not stationary", "engine/sim/controllers.py",
      "self.x = a * self.x + self.sigma * math.sqrt(1 - a * a) * float(self.rng.normal())",
      "self.x = a * self.x + self.sigma * float(self.rng.normal())", *SIM),
    m("sim: penetration signal without the 0.1 offset", "engine/sim/model.py",
      "/ (np.asarray(along, dtype=float)[:, None] + 0.1)", "/ (np.asarray(along, dtype=float)[:, None] + 0.2)", *SIM),
    m("sim: penetration normal from the whisker's x axis", "engine/sim/model.py",
      "np.add.at(out, whisker, penetration_deflection(-dist, local_normal[:, 1:], along))",
      "np.add.at(out, whisker, penetration_deflection(-dist, local_normal[:, :2], along))", *SIM),
    m("worlds: panels on the wrong side of the wall", "engine/sim/build.py",
      "            face = np.array([cx, cy]) + inward[:2] * t / 2  # centre of the wall's inner face",
      "            face = np.array([cx, cy]) - inward[:2] * t / 2  # centre of the wall's inner face", *WORLDS),
    m("worlds: landmark height offset ignored", "engine/sim/build.py",
      "shape = dict(type=_GEOM.mjGEOM_BOX, pos=(x, y, lm.z + lm.size[2] / 2)",
      "shape = dict(type=_GEOM.mjGEOM_BOX, pos=(x, y, lm.size[2] / 2)", *WORLDS),
    m("robot: camera at the base centre's side instead of cam0's", "engine/sim/robot.py",
      "CAMERA_POS = (0.5166, 0.0573, 0.315)", "CAMERA_POS = (0.5166, 0.0, 0.315)", *SIM),
    m("routes: footprint clearance forgets the head's own radius", "engine/sim/controllers.py",
      "dist[len(xy):] - HEAD_RADIUS)", "dist[len(xy):])", *SIM),
    m("evaluate: recall at 100 % precision taken at 90 %", "engine/evaluate.py",
      "full = self.precision >= 1.0", "full = self.precision >= 0.9", "tests/test_evaluate.py"),
    m("sweep: jobs lost with a broken pool are not run again", "engine/sweep.py",
      "                rounds.append(([job], 1))", "                pass", "tests/test_sweep.py"),
    m("routes: partial revisit applied to the reference run", "engine/scenario.py",
      'if role == "query" and self.query_off_route:', 'if role == "reference" and self.query_off_route:',
      "tests/test_cli.py"),
    m("worlds: obstacle map ignores the arena depth", "engine/sim/environment.py",
      "        self.half = np.array([env.arena.half_x, env.arena.half_y])",
      "        self.half = np.array([env.arena.half_x, env.arena.half_x])", *SIM),
    # --- sweeps and their summary
    m("summary: standard deviation with ddof=0", "engine/summary.py",
      "    std = float(x.std(ddof=1))", "    std = float(x.std(ddof=0))", *SWEEP),
    m("summary: normal quantile instead of Student's t", "engine/summary.py",
      "float(stats.t.ppf(0.5 + LEVEL / 2, n - 1))", "float(stats.norm.ppf(0.5 + LEVEL / 2))", *SWEEP),
    m("summary: t with n degrees of freedom", "engine/summary.py",
      "stats.t.ppf(0.5 + LEVEL / 2, n - 1)", "stats.t.ppf(0.5 + LEVEL / 2, n)", *SWEEP),
    m("summary: interval from the std instead of the standard error", "engine/summary.py",
      "* std / math.sqrt(n)", "* std", *SWEEP),
    m("summary: an interval made up for one seed", "engine/summary.py", "    if n < 2:", "    if n < 1:", *SWEEP),
    m("summary: differences b - a", "engine/summary.py",
      "diffs = [va[s] - vb[s] for s in seeds]", "diffs = [vb[s] - va[s] for s in seeds]", *SWEEP),
    m("summary: differences over seeds only one method has", "engine/summary.py",
      "seeds = [s for s in va if s in vb]", "seeds = list(va)", *SWEEP),
    m("summary: settings summarised as metrics", "engine/summary.py",
      "        if key in IDENTITY or key in SETTINGS:", "        if key in IDENTITY:", *SWEEP),
    m("sweep: a failed local seed stops the sweep", "engine/sweep.py",
      "                    yield job, None, describe_failure(exc)\n    except BaseException:",
      "                    raise\n    except BaseException:", *SWEEP),
    m("sweep: a failed Ray seed stops the sweep", "engine/sweep.py",
      "                    yield job, None, describe_failure(exc)\n    finally:",
      "                    raise\n    finally:", *SWEEP),
    m("sweep: colour codes kept in the failure line", "engine/sweep.py",
      'text = " ".join(ANSI.sub("", text).split())', 'text = " ".join(text.split())', *SWEEP),
    m("sweep: Ray's wrapped exception not unwrapped", "engine/sweep.py",
      "    if isinstance(cause, BaseException):\n        exc = cause", "    if False:\n        exc = cause", *SWEEP),
    m("sweep: jobs read environments from the driver's paths", "engine/sweep.py",
      '            entry["environment"] = str(files[entry["environment"]])', "            pass", *SWEEP),
    m("sweep: unshared storage never noticed", "engine/sweep.py",
      "socket.gethostname(), not job.marker or Path(job.marker).exists()", "socket.gethostname(), True", *SWEEP),
    m("sweep: unshared storage warned for every job", "engine/sweep.py",
      'if not result["sees_out"] and not outcome.unshared:', 'if not result["sees_out"]:', *SWEEP),
    m("sweep: --force not passed to the jobs", "engine/sweep.py",
      "SeedJob(data, environments, seed, str(out), tuple(force), progress, marker)",
      "SeedJob(data, environments, seed, str(out), (), progress, marker)", *SWEEP),
    m("sweep: GPU jobs keep the CPU backend", "engine/sweep.py", "    if gpus_per_job > 0:", "    if gpus_per_job > 1:", *SWEEP),
    m("sweep: failed seeds exit 0", "engine/cli.py", "        return EXIT_SEEDS_FAILED", "        return 0", *SWEEP),
    m("aggregate: other scenarios accepted", "engine/aggregate.py",
      'if manifest.get("scenario") != first_manifest.get("scenario") or identity != first_identity:',
      'if manifest.get("scenario") != first_manifest.get("scenario"):', *SWEEP),
    m("aggregate: the seed counted in the scenario's identity", "engine/aggregate.py",
      'resolved.items() if k != "seed"', 'resolved.items() if k != "name"', *SWEEP),
    m("aggregate: unfinished runs not recognised", "engine/aggregate.py",
      'REQUIRED = ("manifest.json", "results.json", "scenario.resolved.yaml")', 'REQUIRED = ("scenario.resolved.yaml",)',
      *SWEEP),
    m("aggregate: a seed given twice accepted", "engine/aggregate.py",
      '        if manifest["seed"] in seen:', "        if False:", *SWEEP),
]

#: Mutants that cannot change a result, kept to document why they survive.
EQUIVALENT = [
    (m("pc: top-down error applied with every edge below", "engine/pc.py",
       "above = self.edge_above.get(e.upper) if self.first_below[e.upper] == e.name else None",
       "above = self.edge_above.get(e.upper)", *PC),
     "only a node with several edges below and one above would see it twice; in MuPNet's tree the "
     "joint node is the only one with several edges below, and it has none above"),
    (m("pc: energies also computed on the first predict of a minibatch", "engine/pc.py",
       "        self.predict_all(energy=steps == 0)", "        self.predict_all(energy=True)", *PC),
     "the row energies of that predict are overwritten by the last one before anything reads them"),
]


def run_tests(tests: tuple[str, ...]) -> bool:
    """True when the tests pass."""
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", "--no-header", *tests]
    return subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True).returncode == 0


def apply_and_test(mutant: Mutant) -> bool:
    """Apply ``mutant``, run its tests, restore the file. True when the mutant was killed."""
    path = ROOT / mutant.path
    original = path.read_text()
    count = original.count(mutant.old)
    if count != 1:
        raise SystemExit(f"{mutant.name}: the line to mutate occurs {count} times in {mutant.path}; update the script")
    try:
        path.write_text(original.replace(mutant.old, mutant.new))
        return not run_tests(mutant.tests)
    finally:
        path.write_text(original)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("only", nargs="*", help="run only mutants whose name starts with one of these")
    ap.add_argument("--list", action="store_true")
    args = ap.parse_args(argv)
    chosen = [mt for mt in MUTANTS if not args.only or any(mt.name.startswith(p) for p in args.only)]
    if args.list:
        for mt in chosen:
            print(f"{mt.name}  ({mt.path}; {', '.join(mt.tests)})")
        return 0
    if not run_tests(tuple(sorted({t for mt in chosen for t in mt.tests}))):
        raise SystemExit("the unmutated suite fails: fix it first")
    killed, survived = 0, []
    t0 = time.perf_counter()
    for i, mt in enumerate(chosen, 1):
        ok = apply_and_test(mt)
        killed += ok
        if not ok:
            survived.append(mt)
        print(f"[{i:2d}/{len(chosen)}] {'killed  ' if ok else 'SURVIVED'} {mt.name}", flush=True)
    for mt, reason in EQUIVALENT:
        print(f"[  equivalent ] {mt.name}: {reason}")
    rate = killed / len(chosen) if chosen else 1.0
    print(f"\nkilled {killed} of {len(chosen)} behaviour-changing mutants: {100 * rate:.0f} % "
          f"(target {100 * TARGET:.0f} %), {time.perf_counter() - t0:.0f} s")
    for mt in survived:
        print(f"  survived: {mt.name} ({mt.path})")
    return 0 if rate >= TARGET else 1


if __name__ == "__main__":
    sys.exit(main())
