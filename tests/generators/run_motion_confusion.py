"""Confusion table of `palpate diagnose` on motion datasets from the independent generator.

    python run_motion_confusion.py --draws 24 --seed 1 [--effects none,clamps-late,...]
                                   [--palpate target/release/palpate] [--timeout 1800]
                                   [-o docs/results/diagnose/motion-independent/confusion]
                                   [--work /tmp/palpate-motion-indep] [--resume [--rediagnose]] [--only 2,3,7]

For every draw: make a dataset with `independent_motion.py` (a horizontally clamped cylinder, shaken at
its clamp, 270 frames at 180 Hz by default; its own truth code, mesh and markers), inject the draw's
effect, run palpate as a user would, `palpate diagnose <dataset> -o <dataset>/diagnosis` (one job at a
time, a per-run timeout, wall time recorded), read its diagnosis.json and compare with truth.json.
Writes <out>/confusion.json and <out>/confusion.md (rewritten after every draw, so an interrupted run
keeps what it has), and per draw <out>/draws/<id>/{truth.json, diagnosis.md}; the datasets, palpate's
diagnosis.json and its logs stay under --work.

Effects (magnitudes drawn per draw, uniformly in the ranges of RANGES):
- none: the generator's cylinder as it is.
- clamps-late: the clamp's record lags the markers by 1 or 2 capture frames (`record_clamps_late.py`),
  two capture streams on two clocks.
- marker-offsets: half of the markers (at least two) declared 1-3 mm from where they are glued, in a
  random direction (markers.csv moved, trajectories untouched).
- clamp-compliance: the clamped face held by springs of a layer 5-15 mm thick of the body's material
  (`--clamp-compliance`); the dataset still declares it clamped.
- gravity-tilt: the truth's gravity turned 2-6 degrees about the cylinder's axis (`--gravity-tilt`); the
  dataset still declares (0, 0, -9.81).

Each effect is assigned in a seeded random order that cycles through the listed ones; the dataset seed
of draw i is 1000 * seed + i (a new object, markers and noise every draw). Scoring, per draw:
- named first: the first effect palpate adopts other than damping (`viscosity`, `viscosity-newtonian`:
  the generator's Kelvin-Voigt damping, which the simplest model lacks) and the background
  (`marker-offsets`, the rest scan's own noise: BACKGROUND) is the injected one's candidate (EXACT); for
  `none`, nothing but damping and the background is adopted. In a marker-offsets draw the background is
  the effect itself, so there it is named whenever it is adopted;
- named: the injected one's candidate is adopted at all;
- within 1.5x: palpate's held-out RMS over its noise floor (the forecast steps) is at most 1.5;
- honest: palpate does not call the motion explained while either ratio (fitted or held out) is above
  1.2x its floor.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))

EFFECTS = ["none", "clamps-late", "marker-offsets", "clamp-compliance", "gravity-tilt"]
# palpate's candidate names -> the effect each is the model of
EXACT = {
    "time-offset": "clamps-late",
    "marker-offsets": "marker-offsets",
    "clamp-compliance": "clamp-compliance",
    "gravity-direction": "gravity-tilt",
}
DAMPING = {"viscosity", "viscosity-newtonian", "viscosity-objective"}
# Present in every draw whatever its effect: the generator's rest scan (markers.csv) is the mean of ten
# noisy frames (sigma/sqrt(10) per axis, never declared to palpate), a constant offset of every marker
# from its declared place that a 270-frame capture resolves; naming it is right in any draw and is
# neither the draw's effect (unless that is marker-offsets) nor a false alarm.
BACKGROUND = {"marker-offsets"}
RANGES = {
    "clamps-late": (1, 2),  # whole capture frames
    "marker-offsets": (1e-3, 3e-3),  # m
    "clamp-compliance": (5e-3, 15e-3),  # m, the layer's thickness
    "gravity-tilt": (2.0, 6.0),  # degrees
}


def draw_plan(seed, n, effects):
    rng = np.random.default_rng([seed, 77])
    order = []
    while len(order) < n:
        order.extend(rng.permutation(effects).tolist())
    plan = []
    for i in range(n):
        eff = order[i]
        r = np.random.default_rng([seed, 78, i])
        if eff == "clamps-late":
            mag = int(r.integers(RANGES[eff][0], RANGES[eff][1] + 1))
        elif eff == "none":
            mag = 0.0
        else:
            mag = float(r.uniform(*RANGES[eff]))
        plan.append({"id": f"{i:03d}-{eff}", "index": i, "effect": eff, "magnitude": mag,
                     "dataset_seed": 1000 * seed + i})
    return plan


def run(cmd, log, timeout=None):
    with open(log, "a") as fh:
        fh.write("$ " + " ".join(cmd) + "\n")
        fh.flush()
        t0 = time.time()
        p = subprocess.run(cmd, stdout=fh, stderr=subprocess.STDOUT, timeout=timeout)
        return p.returncode, time.time() - t0


def offset_markers(ds, magnitude, seed):
    """Moves the declared rest place of a random half of the markers (at least two) by `magnitude` in a
    random direction; returns the moved markers' names."""
    path = os.path.join(ds, "markers.csv")
    with open(path) as fh:
        header, *rows = [line.rstrip("\n") for line in fh if line.strip()]
    rng = np.random.default_rng([seed, 79])
    k = max(2, len(rows) // 2)
    chosen = sorted(rng.choice(len(rows), size=k, replace=False).tolist())
    moved = []
    for i in chosen:
        name, *xyz = rows[i].split(",")
        d = rng.standard_normal(3)
        d *= magnitude / np.linalg.norm(d)
        x = np.array([float(v) for v in xyz]) + d
        rows[i] = f"{name},{x[0]:.9e},{x[1]:.9e},{x[2]:.9e}"
        moved.append(name)
    with open(path, "w") as fh:
        fh.write("\n".join([header, *rows]) + "\n")
    return moved


def make_dataset(d, a, work, log):
    """Generates draw `d`'s dataset under `work`; returns its directory."""
    eff, mag, seed = d["effect"], d["magnitude"], d["dataset_seed"]
    base = os.path.join(work, d["id"])
    if os.path.exists(os.path.join(base, "truth.json")) and a.resume:
        return base
    shutil.rmtree(base, ignore_errors=True)
    gen = [sys.executable, os.path.join(HERE, "independent_motion.py"), "-o", base, "--seed", str(seed),
           "--duration", str(a.duration), "--fps", str(a.fps)]
    if eff == "clamp-compliance":
        gen += ["--clamp-compliance", repr(mag)]
    if eff == "gravity-tilt":
        gen += ["--gravity-tilt", repr(mag)]
    env_note = os.environ.get("OMP_NUM_THREADS")
    rc, _ = run(gen, log)
    if rc != 0:
        raise RuntimeError(f"generator failed (see {log}; OMP_NUM_THREADS={env_note})")
    truth_path = os.path.join(base, "truth.json")
    truth = json.load(open(truth_path))
    if eff == "clamps-late":
        late = base + "-late"
        shutil.rmtree(late, ignore_errors=True)
        rc, _ = run([sys.executable, os.path.join(HERE, "record_clamps_late.py"), base, late, "--frames", str(mag)], log)
        if rc != 0:
            raise RuntimeError(f"record_clamps_late failed (see {log})")
        shutil.rmtree(base)
        os.rename(late, base)
        truth = json.load(open(truth_path))
    if eff == "marker-offsets":
        moved = offset_markers(base, mag, seed)
        truth["injected"] = {"effect": "marker-offsets", "offset_m": mag, "markers": moved}
    truth["confusion_effect"] = eff
    truth["confusion_magnitude"] = mag
    with open(truth_path, "w") as fh:
        json.dump(truth, fh, indent=1)
    return base


def mesh_share(diag):
    """The widening of the held-out check's floor by the mesh's share (m), None without one: the
    held-out check's `discretisation_m`, which every build that widens the floor writes."""
    d = diag["heldout_check"].get("discretisation_m") or 0.0
    return d if d > 0 else None


def score(row, diag):
    adopted = list(diag["adopted"])
    rc, hc = diag["residual_check"], diag["heldout_check"]
    eff = row["effect"]
    background = BACKGROUND - {x for x, e in EXACT.items() if e == eff}
    physical = [x for x in adopted if x not in DAMPING | background]
    row.update(adopted=adopted, fitted_ratio=rc["ratio"], heldout_ratio=hc["ratio"],
               fitted_ratio_noise=rc.get("ratio_noise", rc["ratio"]),
               heldout_ratio_noise=hc.get("ratio_noise", hc["ratio"]),
               mesh_share_m=mesh_share(diag),
               explained=bool(rc["explained"] and hc["explained"]),
               mu_fit=diag["elastic"]["shear_modulus_pa"], nu_fit=diag["elastic"]["poisson_ratio"])
    if eff == "none":
        row["named_first"] = not physical
        row["named"] = not physical
    else:
        row["named_first"] = bool(physical) and EXACT.get(physical[0]) == eff
        row["named"] = any(EXACT.get(x) == eff for x in physical)
    row["within_1_5"] = hc["ratio"] <= 1.5
    row["honest"] = not (row["explained"] and max(rc["ratio"], hc["ratio"]) > 1.2)
    return row


def magnitude_text(eff, mag):
    return {"none": "–", "clamps-late": f"{mag} frame(s)", "marker-offsets": f"{mag * 1e3:.2f} mm",
            "clamp-compliance": f"{mag * 1e3:.1f} mm layer", "gravity-tilt": f"{mag:.2f}°"}[eff]


def write_tables(rows, a, out):
    done = [r for r in rows if "adopted" in r]
    with open(os.path.join(out, "confusion.json"), "w") as fh:
        json.dump({"command": " ".join(sys.argv), "rows": rows}, fh, indent=1)
    n = len(done)
    nf = sum(r["named_first"] for r in done)
    nn = sum(r["named"] for r in done)
    w = sum(r["within_1_5"] for r in done)
    h = sum(r["honest"] for r in done)
    both = sum(r["named_first"] and r["within_1_5"] for r in done)
    lines = [
        "# palpate diagnose on the independent motion generator",
        "",
        f"Command: `python tests/generators/run_motion_confusion.py {' '.join(sys.argv[1:])}`  ",
        f"Draws done: {n} of {len(rows)}. **Named first: {nf} of {n}**; named at all: {nn}; held-out RMS within "
        f"1.5× the floor: {w}; both named first and within 1.5×: {both}; honest verdicts: {h} of {n}.",
        "",
        "'held-out / floor' and 'fitted / floor' are over palpate's floor: the noise floor σ√3, widened in quadrature by "
        "the mesh's share where the final residual stood above the noise and its null could be refitted ('mesh share', "
        "held out); 'noise alone' is over σ√3 without it. 'within 1.5×' reads the held-out ratio over palpate's floor.",
        "",
        "| draw | effect | magnitude | truth μ (kPa), ν | palpate adopted (in order) | named first | held-out / floor | fitted / floor | noise alone: held-out, fitted | mesh share (µm) | explained | μ fit / true | ν fit | s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in done:
        lines.append(
            f"| {r['id']} | {r['effect']} | {magnitude_text(r['effect'], r['magnitude'])} | "
            f"{r['mu_true'] / 1e3:.0f}, {r['nu_true']:.3f} | {', '.join(r['adopted']) or '–'} | "
            f"{'✔' if r['named_first'] else ('named later' if r['named'] else '✘')} | {r['heldout_ratio']:.2f} | "
            f"{r['fitted_ratio']:.2f} | {r['heldout_ratio_noise']:.2f}, {r['fitted_ratio_noise']:.2f} | "
            f"{'–' if r['mesh_share_m'] is None else format(1e6 * r['mesh_share_m'], '.0f')} | "
            f"{'yes' if r['explained'] else 'no'} | {r['mu_fit'] / r['mu_true']:.2f} | "
            f"{r['nu_fit']:.3f} | {r['palpate_seconds']:.0f} |")
    failed = [r for r in rows if r.get("error")]
    if failed:
        lines += ["", "Failed draws: " + "; ".join(f"{r['id']}: {r['error']}" for r in failed)]
    lines += ["", "## Per effect", "", "| effect | draws | named first | named | within 1.5× | honest |", "|---|---|---|---|---|---|"]
    for eff in EFFECTS:
        rs = [r for r in done if r["effect"] == eff]
        if rs:
            lines.append(f"| {eff} | {len(rs)} | {sum(r['named_first'] for r in rs)} | {sum(r['named'] for r in rs)} | "
                         f"{sum(r['within_1_5'] for r in rs)} | {sum(r['honest'] for r in rs)} |")
    with open(os.path.join(out, "confusion.md"), "w") as fh:
        fh.write("\n".join(lines) + "\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--draws", type=int, default=24)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--effects", default=",".join(EFFECTS))
    ap.add_argument("--palpate", default="target/release/palpate")
    ap.add_argument("--timeout", type=float, default=1800)
    ap.add_argument("--duration", type=float, default=1.5)
    ap.add_argument("--fps", type=float, default=180.0)
    ap.add_argument("-o", "--out", default="docs/results/diagnose/motion-independent/confusion")
    ap.add_argument("--work", default="/tmp/palpate-motion-indep")
    ap.add_argument("--resume", action="store_true", help="keep datasets and diagnoses already made under --work")
    ap.add_argument("--rediagnose", action="store_true",
                    help="with --resume: keep the datasets made under --work, diagnose every one again")
    ap.add_argument("--only", default=None,
                    help="comma-separated draw indices (e.g. 2,3,7): run only these draws of the plan; "
                         "the others are left out of the tables")
    a = ap.parse_args()
    effects = a.effects.split(",")
    unknown = sorted(set(effects) - set(EFFECTS))
    if unknown:
        ap.error(f"unknown effects {unknown}; known: {EFFECTS}")
    os.makedirs(a.out, exist_ok=True)
    os.makedirs(a.work, exist_ok=True)
    rows = draw_plan(a.seed, a.draws, effects)
    if a.only:
        only = {int(i) for i in a.only.split(",")}
        rows = [r for r in rows if r["index"] in only]
    for row in rows:
        log = os.path.join(a.work, row["id"] + ".log")
        try:
            ds = make_dataset(row, a, a.work, log)
            truth = json.load(open(os.path.join(ds, "truth.json")))
            row.update(mu_true=truth["mu_Pa"], nu_true=truth["nu"], truth_seconds=truth["seconds"])
            out = os.path.join(ds, "diagnosis")
            if a.rediagnose or not (a.resume and os.path.exists(os.path.join(out, "diagnosis.json"))):
                shutil.rmtree(out, ignore_errors=True)
                rc, secs = run([a.palpate, "diagnose", ds, "-o", out], log, timeout=a.timeout)
                if rc != 0:
                    raise RuntimeError(f"palpate diagnose exited {rc} (see {log})")
                row["palpate_seconds"] = secs
                with open(os.path.join(out, "wall_seconds.txt"), "w") as fh:
                    fh.write(f"{secs:.1f}\n")
            else:
                timed = os.path.join(out, "wall_seconds.txt")
                row["palpate_seconds"] = float(open(timed).read()) if os.path.exists(timed) else float("nan")
            diag = json.load(open(os.path.join(out, "diagnosis.json")))
            score(row, diag)
            keep = os.path.join(a.out, "draws", row["id"])
            os.makedirs(keep, exist_ok=True)
            shutil.copy(os.path.join(out, "diagnosis.md"), keep)
            shutil.copy(os.path.join(ds, "truth.json"), keep)
        except subprocess.TimeoutExpired:
            row["error"] = f"timeout after {a.timeout:.0f} s"
        except Exception as e:  # noqa: BLE001 - a failed draw is recorded, the table goes on
            row["error"] = str(e)
        write_tables(rows, a, a.out)
        print(f"{row['id']}: {row.get('adopted', row.get('error'))}", flush=True)


if __name__ == "__main__":
    main()
