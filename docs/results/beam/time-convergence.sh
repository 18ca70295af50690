#!/usr/bin/env bash
# The beam's four-run diagnosis at four time discretisations: the implicit midpoint rule at the
# import's substeps (2 on the gravity runs, 1 on the 52 g runs) and at 2 on every run, BDF2 at its
# rule's substeps (3 and 2) and at twice as many; the parameters, the verdict and the step's own
# error at the final model of each, for "Converged in time" in README.md. Run from the repository
# root:
#     bash docs/results/beam/time-convergence.sh      (≈ 6 min on 2 cores, alone)
set -euo pipefail
P=$(realpath "${PALPATE:-target/release/palpate}")
B=models/silicone-beam
OUT=${OUT:-out/beam-time}
RUNS="gravity_V2_a gravity_V2_b load52_V2_a load52_V2_b"
for case in midpoint-import midpoint-2 bdf2-rule bdf2-double; do
  for r in $RUNS; do
    hang=""; case $r in load52*) hang="--hang 0.052@free_end";; esac
    scheme=bdf2; case $case in midpoint*) scheme=midpoint;; esac
    $P -q import c3d $B/beam_$r.c3d --mesh $B/beam-coarse.msh --places $B/marker-places.csv \
       --clamps clamp --gravity=-9.81,0,0 --density 1070 $hang --scheme $scheme -o "$OUT/$case/$r"
    k=""
    case $case-$r in
      bdf2-double-gravity*) k=6;; bdf2-double-load52*) k=4;; midpoint-2-*) k=2;;
    esac
    [ -z "$k" ] || sed -i "s/^dt = \(.*\)/dt = \1\nsubsteps = $k/" "$OUT/$case/$r/dataset.toml"
  done
  (cd "$OUT/$case" && /usr/bin/time -f "$case: %e s wall" "$P" -q diagnose gravity_V2_a \
     --with load52_V2_a --held-out gravity_V2_b --held-out load52_V2_b -o diag)
done
python3 - "$OUT" <<'PY'
import json, sys
out = sys.argv[1]
print("| integration | verdict | μ (kPa) | viscosity (Pa·s^h) | h | creep g | creep τ (s) | step error, fitted runs (µm) | held-out RMS (mm) |")
print("|---|---|---|---|---|---|---|---|---|")
for case in ("midpoint-import", "midpoint-2", "bdf2-rule", "bdf2-double"):
    d = json.load(open(f"{out}/{case}/diag/diagnosis.json"))
    v = {p["name"].split(" (")[0]: p["value"] for p in d["values"]}
    errs = " / ".join("%.0f" % (1e6 * e["measured"]["error_m"]) for e in d["fitted_step_errors"][:2])
    print("| %s | %s | %.2f | %.1f | %.3f | %.4f | %.3f | %s | %.3f |" % (
        case, ", ".join(d["adopted"]), 1e-3 * v["μ"], v["viscosity"], v["power-law index h"],
        v["creep: relaxed fraction g"], v["creep: relaxation time τ"], errs, 1e3 * d["heldout_rms_m"][1]))
PY
