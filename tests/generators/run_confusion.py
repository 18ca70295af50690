"""Confusion table of `palpate diagnose` on datasets from the independent generator.

    python run_confusion.py --draws 40 --seed 1 [--shapes block,dome,cylinder] [--effects none,inclusion,...]
                            [--palpate target/release/palpate] [--timeout 1800] [--snr-threshold 5]
                            [-o docs/results/diagnose/static-independent] [--work /tmp/palpate-indep] [--quick] [--resume]
    python run_confusion.py --draws 2 --quick          # smoke test: a few minutes

For every draw: generate a dataset (independent_static.generate), run palpate as a user would,
`palpate diagnose <dataset> -o <dataset>/diagnosis` (one job at a time, a per-run timeout, wall time
recorded), read its diagnosis.json and compare with truth.json. Writes <out>/confusion.json and
<out>/confusion.md (rewritten after every draw, so an interrupted run keeps what it has), and per draw
<out>/draws/<id>/{truth.json, diagnosis.json, diagnosis.md, palpate.log}. Datasets stay under --work.

Effects and shapes are assigned in a seeded random order that cycles through every listed one (so a
run of N >= 13 draws holds every effect), each draw's dataset seed = 1000 * seed + draw index.
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
import traceback

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import independent_static as gen  # noqa: E402

# ---------------------------------------------------------------------------------------------
# palpate's candidate names -> the generator's effect names.
# EXACT: the candidate is palpate's model of that effect. RELATED: a coarser model of the same
# physical cause (counted separately, never as a correct name).
EXACT = {
    "calibration": {"sensor-nonlinearity"},
    "tilt-each": {"friction", "tilt-each"},
    "boundary": {"compliant-support"},
    "support": {"compliant-support"},
    "registration-each": {"registration-each"},
    "force-scale-each": {"force-scale"},
    "gravity": {"gravity"},
    "inclusion": {"inclusion"},
    "layer": {"layer"},
    "stiffening": {"stiffening"},
    "noise": {"noise"},
}
RELATED = {
    "tilt": {"friction", "tilt-each"},
    "registration": {"registration-each", "stand-off"},
    "inhomogeneity": {"inclusion", "layer"},
    "calibration": {"force-scale"},
    "layer": {"inclusion"},
    "inclusion": {"layer"},
}
PALPATE_CANDIDATES = ["calibration", "tilt", "tilt-each", "contact-radius", "boundary", "support", "registration", "registration-each",
                      "force-scale-each", "gravity", "inhomogeneity", "layer", "inclusion", "stiffening", "noise",
                      "rest-noise"]
# Present in every draw whatever its effect: the generator's rest scan is the mean of ten noisy frames
# (RANGES["rest_noise_factor"], never declared to palpate), so naming it is right in any draw and is
# neither the draw's effect nor a false alarm; the verdict on the draw's own effect leaves it aside.
BACKGROUND = {"rest-noise"}
# Effects palpate's base model holds by construction, so that a clean verdict is the right one: a marker
# off the mesh surface is embedded as a material point carried rigidly by its surface patch (palpate_fem's
# dataset embedding: "markers keep their offsets"), which is what the generator's stand-off posts are.
BUILT_IN = {"stand-off"}
# effects of the generator that no palpate candidate models exactly
UNMODELLED = sorted(set(gen.EFFECTS) - {"none"} - set().union(*EXACT.values()) - BUILT_IN)

SNR_BINS = [0, 3, 10, 30, 100, math.inf]


def verdict_of(d):
    """Short verdict from diagnosis.json (the same cases as ResidualCheck::verdict), on the draw's own
    effect: background effects (BACKGROUND) adopted alone leave a clean verdict clean."""
    rc = d["residual_check"]
    adopted = [a for a in d["adopted"] if a not in BACKGROUND]
    if not adopted:
        if not rc["judged"]:
            return "no-effect (unjudged)"
        return "clean" if rc["explained"] else "NOT clean"
    if not rc["judged"]:
        return "adopted (not judged)"
    return "adopted" if rc["explained"] else "adopted, still above floor"


def point_triangle_distance(P, A, B, C):
    """Distance from points P (m,3) to triangles (A, B, C each (t,3)): (m,t)."""
    P = P[:, None, :]
    AB, AC = B - A, C - A
    N = np.cross(AB, AC)
    N = N / np.linalg.norm(N, axis=1)[:, None]
    AP = P - A
    dplane = np.einsum("mti,ti->mt", AP, N)
    Q = P - dplane[..., None] * N  # projection on the plane
    # barycentric coordinates of Q
    d00, d01, d11 = (AB * AB).sum(1), (AB * AC).sum(1), (AC * AC).sum(1)
    AQ = Q - A
    d20, d21 = np.einsum("mti,ti->mt", AQ, AB), np.einsum("mti,ti->mt", AQ, AC)
    den = d00 * d11 - d01 * d01
    v = (d11 * d20 - d01 * d21) / den
    w = (d00 * d21 - d01 * d20) / den
    inside = (v >= 0) & (w >= 0) & (v + w <= 1)

    def seg(P, U, V):
        UV = V - U
        t = np.clip(np.einsum("mti,ti->mt", P - U, UV) / (UV * UV).sum(1), 0, 1)
        return np.linalg.norm(P - (U + t[..., None] * UV), axis=2)

    edge = np.minimum(np.minimum(seg(P, A, B), seg(P, B, C)), seg(P, C, A))
    return np.where(inside, np.abs(dplane), edge)


def marker_surface_offsets(ds):
    """RMS and max distance of the declared rest markers (markers.csv) from the dataset mesh's boundary
    surface: palpate embeds each marker at the closest surface point and compares that point's
    simulated position with the measured one, so this offset stays in every measurement's residual."""
    import gmsh
    import truthfem as tf
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.open(os.path.join(ds, "mesh.msh"))
        tags, coords, _ = gmsh.model.mesh.getNodes()
        X = coords.reshape(-1, 3)
        index = {int(t): i for i, t in enumerate(tags)}
        _, en = gmsh.model.mesh.getElementsByType(4)
        T = np.vectorize(index.__getitem__)(en.reshape(-1, 4).astype(np.int64))
    finally:
        gmsh.finalize()
    F = tf.boundary_faces(T)
    M = np.loadtxt(os.path.join(ds, "markers.csv"), delimiter=",", skiprows=1, usecols=(1, 2, 3), ndmin=2)
    d = np.concatenate([point_triangle_distance(M[i:i + 50], X[F[:, 0]], X[F[:, 1]], X[F[:, 2]]).min(axis=1)
                        for i in range(0, len(M), 50)])
    return float(np.sqrt(np.mean(d**2))), float(d.max())


def snr_fields(tr):
    """SNR on positions (the primary one) and on displacements, from a truth.json (older files had the
    displacement one under "snr" and the positions one under "snr_positions")."""
    if "snr_displacement" in tr:
        return {"snr": tr["snr"], "snr_displacement": tr["snr_displacement"]}
    return {"snr": tr["snr_positions"], "snr_displacement": tr["snr"]}


def field(obj, *names):
    """The first of `names` present in `obj`: diagnosis.json schema 1 names fields with their units
    (`fitted_rms_m`); documents written before it used the bare names (`fitted_rms`)."""
    for name in names:
        if obj is not None and name in obj:
            return obj[name]
    return None


def elastic_of(d):
    """(E, nu) from diagnosis.json: the `elastic` object (schema 1) or the older `young_poisson` pair."""
    if "elastic" in d:
        e = d["elastic"]
        return field(e, "young_modulus_pa", "young_pa", "E_pa"), field(e, "poisson_ratio", "nu")
    return d["young_poisson"][0], d["young_poisson"][1]


def fill_from_diagnosis(row, d):
    """The row's palpate fields from a diagnosis.json (either schema)."""
    rc = d["residual_check"]
    b, a = d["before"], d["after"]
    E_fit, nu_fit = elastic_of(d)
    row.update(
        adopted=[x for x in d["adopted"]], verdict=verdict_of(d), ratio=rc["ratio"], z=rc["z"], judged=rc["judged"],
        ratio_noise=rc.get("ratio_noise", rc["ratio"]), discretisation_m=rc.get("discretisation_m"),
        floor_m=field(d, "noise_floor_m", "noise_floor"),
        before_fitted_rms_m=field(b, "fitted_rms_m", "fitted_rms"), after_fitted_rms_m=field(a, "fitted_rms_m", "fitted_rms"),
        before_heldout_rms_m=field(b, "heldout_rms_m", "heldout_rms"), after_heldout_rms_m=field(a, "heldout_rms_m", "heldout_rms"),
        ambiguous_with=sorted({x for st in d["steps"] for x in st.get("ambiguous_with", [])}),
        E_fit=E_fit, nu_fit=nu_fit, palpate_seconds=field(d, "run_time_s", "seconds"),
        mesh_error_rms_m=field(d.get("mesh_error"), "rms_m", "rms"),
    )
    n = d.get("noise") or {}
    row["sigma_hat_m"] = field(n, "estimate_m", "estimate")
    floor = field(n, "floor_m", "floor")
    # with `noise` adopted the harness also states the ratio to palpate's recomputed floor sigma_hat sqrt(3)
    row["ratio_vs_recomputed_floor"] = (row["after_fitted_rms_m"] / floor) if n.get("fired") and floor else None
    return row


def score(row):
    eff, names = row["effect"], row.get("adopted") or []
    row["named_exact"] = any(eff in EXACT.get(n, ()) for n in names)
    row["named_related"] = any(eff in RELATED.get(n, ()) for n in names)
    row["detected"] = row.get("verdict") not in (None, "clean", "error", "timeout")
    row["false_clean"] = eff != "none" and row.get("verdict") == "clean"
    if eff in BUILT_IN:
        # modelled by the base model: clean is the right verdict, anything adopted is not its name
        row["named_exact"] = row.get("verdict") == "clean"
        row["detected"] = True
        row["false_clean"] = False
    return row


def reused(ds, seed, shape, effect, args):
    """The truth of a dataset generated before for this very draw (seed, shape, effect, quick), or
    None: `--reuse-datasets` diagnoses the same data again with another palpate."""
    tj = os.path.join(ds, "truth.json")
    if not os.path.exists(tj):
        return None
    with open(tj) as fh:
        tr = json.load(fh)
    same = (tr.get("seed"), tr.get("shape"), tr.get("effect"), tr.get("quick")) == (seed, shape, effect, args.quick)
    return tr if same else None


def run_one(i, args, work, outdir):
    seed = 1000 * args.seed + i
    shape = args.shape_order[i]
    effect = args.effect_order[i]
    did = f"{i:03d}-{shape}-{effect}"
    ds = os.path.join(work, did)
    row = {"draw": i, "id": did, "seed": seed, "shape": shape, "effect": effect}
    t0 = time.time()
    tr = reused(ds, seed, shape, effect, args) if args.reuse_datasets else None
    if tr is None:
        if os.path.exists(ds):
            shutil.rmtree(ds)
        try:
            tr = gen.generate(ds, seed, shape, effect, quick=args.quick, verbose=True)
        except Exception as e:  # a generator failure is the generator's: recorded and shown
            row.update(verdict="generator-error", error=f"{type(e).__name__}: {e}", gen_traceback=traceback.format_exc())
            return row
    else:
        print(f"  reusing the dataset in {ds} (generated before: {tr['seconds']:.1f} s)", flush=True)
        shutil.rmtree(os.path.join(ds, "diagnosis"), ignore_errors=True)
        t0 -= tr["seconds"]
    row.update(magnitude=tr["magnitude"], **snr_fields(tr),
               E_true=tr["E_Pa"], nu_true=tr["nu"], sigma=tr["marker_noise_declared_m"],
               markers=tr["markers"], measurements=tr["measurements"], observed=tr["observed_entries"],
               rms_disp_m=tr["rms_marker_displacement_m"], max_disp_m=tr["max_marker_displacement_m"],
               dataset_tets=tr["dataset_mesh"]["tets"], truth_tets=tr["truth_mesh"]["tets"],
               generate_s=time.time() - t0)
    row["marker_offset_rms_m"], row["marker_offset_max_m"] = marker_surface_offsets(ds)
    rep = os.path.join(ds, "diagnosis")
    cmd = [args.palpate, "diagnose", ds, "-o", rep]
    row["command"] = " ".join(cmd)
    t1 = time.time()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout)
        row["seconds"] = time.time() - t1
        row["exit_code"] = p.returncode
        log = p.stdout + "\n--- stderr ---\n" + p.stderr
    except subprocess.TimeoutExpired as e:
        row["seconds"] = time.time() - t1
        row["verdict"] = "timeout"
        row["error"] = f"no result within {args.timeout} s"
        log = (e.stdout or b"").decode(errors="replace") if isinstance(e.stdout, bytes) else (e.stdout or "")
    d_out = os.path.join(outdir, "draws", did)
    os.makedirs(d_out, exist_ok=True)
    with open(os.path.join(d_out, "palpate.log"), "w") as fh:
        fh.write(" ".join(cmd) + "\n" + log)
    shutil.copy(os.path.join(ds, "truth.json"), d_out)
    if row.get("verdict") == "timeout":
        return row
    js = os.path.join(rep, "diagnosis.json")
    if row["exit_code"] != 0 or not os.path.exists(js):
        row["verdict"] = "error"
        tail = [ln for ln in log.strip().splitlines() if ln.strip() and ln.strip() != "--- stderr ---"]
        row["error"] = " | ".join(tail[-3:])[-600:]
        return row
    for f in ("diagnosis.json", "diagnosis.md"):
        shutil.copy(os.path.join(rep, f), d_out)
    fill_from_diagnosis(row, json.load(open(js)))
    return row


def snr_bin(s):
    for lo, hi in zip(SNR_BINS[:-1], SNR_BINS[1:]):
        if lo <= s < hi:
            return f"{lo:g}-{hi:g}" if hi < math.inf else f">={lo:g}"
    return "?"


def summarise(rows, args):
    done = [r for r in rows if r.get("verdict")]
    eff_rows = sorted({r["effect"] for r in done}, key=gen.EFFECTS.index)
    cols = PALPATE_CANDIDATES + ["(clean)", "(NOT clean)", "(error/timeout)"]
    table = {e: {c: 0 for c in cols} for e in eff_rows}
    for r in done:
        t = table[r["effect"]]
        v = r["verdict"]
        if v in ("error", "timeout", "generator-error"):
            t["(error/timeout)"] += 1
        else:
            for a in r.get("adopted") or []:
                t[a] = t.get(a, 0) + 1
            if not [a for a in r.get("adopted") or [] if a not in BACKGROUND]:
                t["(clean)" if v == "clean" else "(NOT clean)"] += 1
    bins = {}
    for r in done:
        if r["effect"] == "none" or "snr" not in r or r["verdict"] in ("error", "timeout", "generator-error"):
            continue
        b = bins.setdefault(snr_bin(r["snr"]), {"draws": 0, "detected": 0, "named_exact": 0})
        b["draws"] += 1
        b["detected"] += int(r["detected"])
        b["named_exact"] += int(r["named_exact"])
    ok = [r for r in done if r["verdict"] not in ("error", "timeout", "generator-error")]
    secs = [r["seconds"] for r in ok if "seconds" in r]
    return {
        "draws_done": len(done), "draws_requested": args.draws,
        "table": table, "columns": cols,
        "false_clean_above_threshold": sum(1 for r in ok if r["false_clean"] and r["snr"] > args.snr_threshold),
        "false_clean_any_snr": sum(1 for r in ok if r["false_clean"]),
        "none_draws": {"total": sum(1 for r in ok if r["effect"] == "none"),
                       "clean": sum(1 for r in ok if r["effect"] == "none" and r["verdict"] == "clean")},
        "named_exact": sum(1 for r in ok if r["named_exact"]),
        "with_effect": sum(1 for r in ok if r["effect"] != "none"),
        "errors": [{"id": r["id"], "verdict": r["verdict"], "error": r.get("error")} for r in done if r["verdict"] in ("error", "timeout", "generator-error")],
        "detection_by_snr": {k: bins[k] for k in sorted(bins, key=lambda s: float(s.split("-")[0].lstrip(">=")))},
        "palpate_seconds": {"median": float(np.median(secs)) if secs else None, "min": min(secs) if secs else None, "max": max(secs) if secs else None},
    }


def write_reports(rows, args, outdir):
    s = summarise(rows, args)
    meta = {"command": args.command_line, "palpate": args.palpate, "palpate_version": args.palpate_version, "palpate_sha256": args.palpate_sha256,
            "seed": args.seed, "draws": args.draws, "quick": args.quick, "timeout_s": args.timeout,
            "snr_threshold": args.snr_threshold,
            "env": {k: os.environ.get(k) for k in ("RAYON_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")}, "shapes": args.shapes, "effects": args.effects,
            "mapping_exact": {k: sorted(v) for k, v in EXACT.items()},
            "mapping_related": {k: sorted(v) for k, v in RELATED.items()},
            "effects_without_an_exact_candidate": UNMODELLED}
    with open(os.path.join(outdir, "confusion.json"), "w") as fh:
        json.dump({"meta": meta, "summary": s, "rows": rows}, fh, indent=1, default=str)
    L = []
    L.append("# palpate diagnose on the independent generator\n")
    L.append(f"Command: `{args.command_line}`  ")
    L.append("Environment: " + ", ".join(f"{k}={os.environ.get(k)}" for k in ("RAYON_NUM_THREADS", "OMP_NUM_THREADS") if os.environ.get(k)) + "  ")
    L.append(f"palpate: `{args.palpate}` ({args.palpate_version}, sha256 {args.palpate_sha256[:12]}); per-run timeout {args.timeout} s; generator `tests/generators/independent_static.py`{' (quick mode)' if args.quick else ''}.\n")
    L.append(f"Draws done: {s['draws_done']} of {args.draws}. With an effect: {s['with_effect']}; named exactly: {s['named_exact']}. "
             f"**False clean** (verdict clean while the truth has an effect with SNR > {args.snr_threshold:g}): **{s['false_clean_above_threshold']}** "
             f"(at any SNR: {s['false_clean_any_snr']}). 'none' draws judged clean: {s['none_draws']['clean']} of {s['none_draws']['total']}. "
             f"palpate wall time per diagnosis: median {s['palpate_seconds']['median'] or float('nan'):.0f} s (min {s['palpate_seconds']['min'] or float('nan'):.0f}, max {s['palpate_seconds']['max'] or float('nan'):.0f}).\n")
    L.append("SNR = ‖observed marker positions with the effect − the same draw without it‖₂ / declared σ over all observed entries "
             "(noise-free truth; for `noise`, the extra noise itself); 'SNR disp' = the same on displacements against each world's own rest scan, which leaves out a shift common to the rest scan and the measurements (the gravity sag, the stand-off posts). "
             "Ratios are RMS / noise floor σ√3 (fitted data; held-out in brackets); 'mesh error' is palpate's own estimate of its dataset mesh's discretisation error at the markers (u_h − u_h/2, which its approximation-error correction then removes). "
             "'marker offset' = RMS distance of the declared rest markers from the dataset mesh's surface (facets inside a curved surface, stand-off posts, rest-scan noise): palpate compares the simulated position of the closest surface point with the measured marker, so this offset stays in every measurement's residual. "
             "'adopted (not judged)': palpate adopted `noise`, after which it does not test the residual (ResidualCheck judged = false); the harness adds the ratio to palpate's recomputed floor σ̂√3.\n")
    L.append("## Per draw\n")
    L.append("| draw | shape | effect | magnitude | SNR | SNR disp | palpate adopted | verdict | ambiguous with | RMS before/floor | RMS after/floor | mesh error/floor | marker offset/floor | E fit/true | ν fit/true | s |")
    L.append("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        if "ratio" in r:
            fl = r["floor_m"]
            before = f"{r['before_fitted_rms_m'] / fl:.2f} ({r['before_heldout_rms_m'] / fl:.2f})"
            after = f"{r['after_fitted_rms_m'] / fl:.2f} ({r['after_heldout_rms_m'] / fl:.2f})"
            efit = f"{r['E_fit'] / r['E_true']:.2f}"
            nufit = f"{r['nu_fit']:.2f}/{r['nu_true']:.2f}"
            merr = f"{r['mesh_error_rms_m'] / fl:.2f}" if r.get("mesh_error_rms_m") else "–"
            moff = f"{r['marker_offset_rms_m'] / fl:.2f}" if r.get("marker_offset_rms_m") is not None else "–"
        else:
            before = after = efit = nufit = merr = moff = "–"
        ad = ", ".join(r.get("adopted") or []) or "–"
        mark = " ✔" if r.get("named_exact") else (" ~" if r.get("named_related") else "")
        v = r.get("verdict", "?")
        if r.get("ratio_vs_recomputed_floor"):
            v += f"; {r['ratio_vs_recomputed_floor']:.2f}× σ̂√3"
        if v in ("error", "timeout", "generator-error"):
            v = f"**{v}**: " + r.get("error", "").replace("--- stderr --- | ", "").replace("|", "\\|")
        L.append(f"| {r['id']} | {r['shape']} | {r['effect']} | {r.get('magnitude', float('nan')):.3g} | {r.get('snr', float('nan')):.1f} | {r.get('snr_displacement', float('nan')):.1f} | {ad}{mark} | {v} | {', '.join(r.get('ambiguous_with') or []) or '–'} | {before} | {after} | {merr} | {moff} | {efit} | {nufit} | {r.get('seconds', float('nan')):.0f} |")
    L.append("\n✔ = an adopted candidate is palpate's model of the injected effect (EXACT table); ~ = a related, coarser model (RELATED table).\n")
    L.append("## Confusion table (truth effect × what palpate named; a draw with two adopted effects counts in both columns)\n")
    cols = [c for c in s["columns"] if any(s["table"][e][c] for e in s["table"])]
    L.append("| truth \\ named | " + " | ".join(cols) + " |")
    L.append("|---|" + "---|" * len(cols))
    for e, t in s["table"].items():
        L.append(f"| {e} | " + " | ".join(str(t[c]) if t[c] else "" for c in cols) + " |")
    L.append("\n## Detection against SNR (draws with an effect)\n")
    L.append("| SNR bin | draws | detected (not clean) | named exactly |")
    L.append("|---|---|---|---|")
    for k, b in s["detection_by_snr"].items():
        L.append(f"| {k} | {b['draws']} | {b['detected']} | {b['named_exact']} |")
    if s["errors"]:
        L.append("\n## Failures\n")
        for e in s["errors"]:
            L.append(f"- {e['id']}: {e['verdict']}: `{(e['error'] or '').replace('--- stderr --- | ', '')}`")
    L.append("\n## Name mapping (palpate candidate → generator effect)\n")
    L.append("| palpate candidate | exact | related |")
    L.append("|---|---|---|")
    for c in PALPATE_CANDIDATES:
        L.append(f"| {c} | {', '.join(sorted(EXACT.get(c, []))) or '–'} | {', '.join(sorted(RELATED.get(c, []))) or '–'} |")
    L.append(f"\nEffects of the generator that no palpate candidate models exactly: {', '.join(UNMODELLED)}.")
    L.append(f"\nHeld by palpate's base model, so that a clean verdict is the right name: {', '.join(sorted(BUILT_IN))} "
             "(a marker off the mesh surface is carried rigidly by its surface patch).")
    L.append(f"\nIn every draw, whatever its effect: {', '.join(sorted(BACKGROUND))} (the generator's rest scan is the mean "
             "of ten noisy frames, undeclared): counted in its column when named, left aside in the verdict on the draw's "
             "own effect.")
    with open(os.path.join(outdir, "confusion.md"), "w") as fh:
        fh.write("\n".join(L) + "\n")
    return s


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--draws", type=int, default=40)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--shapes", default=",".join(gen.SHAPES))
    ap.add_argument("--effects", default=",".join(gen.EFFECTS))
    ap.add_argument("--palpate", default="target/release/palpate")
    ap.add_argument("--timeout", type=float, default=1800)
    ap.add_argument("--snr-threshold", type=float, default=5.0)
    ap.add_argument("-o", "--out", default=None)
    ap.add_argument("--work", default="/tmp/palpate-indep")
    ap.add_argument("--quick", action="store_true", help="coarse truth mesh, <= 4 contacts: a smoke test")
    ap.add_argument("--rescore", action="store_true", help="only re-read the saved draws/*/diagnosis.json of -o and rewrite the reports")
    ap.add_argument("--resume", action="store_true", help="keep the finished rows of an earlier confusion.json in -o")
    ap.add_argument("--reuse-datasets", action="store_true",
                    help="diagnose a draw's dataset already in --work (same seed, shape and effect) again instead of generating it anew: another palpate on the same data")
    args = ap.parse_args()
    args.command_line = "python tests/generators/run_confusion.py " + " ".join(sys.argv[1:])
    shapes_l = [s for s in args.shapes.split(",") if s]
    effects_l = [e for e in args.effects.split(",") if e]
    for e in effects_l:
        if e not in gen.EFFECTS:
            ap.error(f"unknown effect {e!r} (known: {', '.join(gen.EFFECTS)})")
    for s_ in shapes_l:
        if s_ not in gen.SHAPES:
            ap.error(f"unknown shape {s_!r}")
    if not os.path.exists(args.palpate):
        ap.error(f"palpate binary not found: {args.palpate} (build it: cargo build --release -p palpate)")
    args.palpate = os.path.abspath(args.palpate)
    import hashlib
    with open(args.palpate, "rb") as fh:
        args.palpate_sha256 = hashlib.sha256(fh.read()).hexdigest()
    try:
        args.palpate_version = subprocess.run([args.palpate, "--version"], capture_output=True, text=True, timeout=30).stdout.strip()
    except Exception:
        args.palpate_version = "?"
    outdir = args.out or ("/tmp/palpate-indep-smoke" if args.quick else "docs/results/diagnose/static-independent")
    os.makedirs(outdir, exist_ok=True)
    # blocks of len(effects) draws: a shuffled effect list, then shuffled shape lists covering the block
    # (prefix-stable: the first draws of a longer run are those of a shorter one with the same seed)
    rng = np.random.default_rng([args.seed, 99])
    args.effect_order, args.shape_order = [], []
    while len(args.effect_order) < args.draws:
        args.effect_order += list(rng.permutation(effects_l))
        block = [s_ for _ in range(math.ceil(len(effects_l) / len(shapes_l))) for s_ in rng.permutation(shapes_l)]
        args.shape_order += block[: len(effects_l)]
    args.effect_order = [str(e) for e in args.effect_order[: args.draws]]
    args.shape_order = [str(s_) for s_ in args.shape_order[: args.draws]]
    args.shapes, args.effects = shapes_l, effects_l
    rows = []
    if args.resume and os.path.exists(os.path.join(outdir, "confusion.json")):
        old = json.load(open(os.path.join(outdir, "confusion.json")))["rows"]
        rows = [r for r in old if r.get("verdict")]
    if args.rescore:
        old = json.load(open(os.path.join(outdir, "confusion.json")))
        args.command_line = old["meta"]["command"]
        rows = old["rows"]
        for r in rows:
            tj = os.path.join(outdir, "draws", r["id"], "truth.json")
            if os.path.exists(tj):
                r.pop("snr_positions", None)
                r.update(snr_fields(json.load(open(tj))))
            ds = os.path.join(args.work, r["id"])
            if "marker_offset_rms_m" not in r and os.path.exists(os.path.join(ds, "mesh.msh")):
                r["marker_offset_rms_m"], r["marker_offset_max_m"] = marker_surface_offsets(ds)
            js = os.path.join(outdir, "draws", r["id"], "diagnosis.json")
            if os.path.exists(js):
                fill_from_diagnosis(r, json.load(open(js)))
            score(r)
        s = write_reports(rows, args, outdir)
        print(json.dumps({k: s[k] for k in ("draws_done", "named_exact", "with_effect", "false_clean_above_threshold")}))
        return
    done_ids = {r["id"] for r in rows}
    for i in range(args.draws):
        did = f"{i:03d}-{args.shape_order[i]}-{args.effect_order[i]}"
        if did in done_ids:
            continue
        print(f"=== draw {i + 1}/{args.draws}: {did}", flush=True)
        row = score(run_one(i, args, args.work, outdir))
        rows.append(row)
        rows.sort(key=lambda r: r["draw"])
        print(f"    -> {row.get('verdict')} adopted={row.get('adopted')} SNR={row.get('snr', float('nan')):.1f} "
              f"palpate {row.get('seconds', float('nan')):.0f} s {row.get('error', '')}", flush=True)
        write_reports(rows, args, outdir)
    s = write_reports(rows, args, outdir)
    print(json.dumps({k: s[k] for k in ("draws_done", "named_exact", "with_effect", "false_clean_above_threshold", "palpate_seconds")}))


if __name__ == "__main__":
    main()
