#!/usr/bin/env bash
# The measured-beam evidence: import the four bundled captures on the coarse mesh, fit
# the diagnosed model's elastic law and damping (Neo-Hookean, Poisson's ratio held at 0.49, a
# Newtonian viscosity, the hanging weight's inertia; no creep branch) on all four runs ->
# models/silicone-beam/fit.json, then leave one run out:
# fit three, predict the fourth with `palpate validate`. Run from the repository root:
#     bash docs/results/beam/run.sh            (≈ 1 min on 2 cores)
set -euo pipefail
P=${PALPATE:-target/release/palpate}
B=models/silicone-beam
OUT=${OUT:-out/beam-evidence}
RUNS="gravity_V2_a gravity_V2_b load52_V2_a load52_V2_b"
FIT="--params mu,viscosity --poisson 0.49 --hanging-inertia --initial mu=4.6e4,viscosity=240 --max-iters 60"
mkdir -p "$OUT"
for r in $RUNS; do
  hang=""; case $r in load52*) hang="--hang 0.052@free_end";; esac
  $P import c3d $B/beam_$r.c3d --mesh $B/beam-coarse.msh --places $B/marker-places.csv \
     --clamps clamp --gravity=-9.81,0,0 --density 1070 $hang -o "$OUT/$r" > "$OUT/import-$r.log"
done
# All four runs -> the shipped model.
$P fit-motion $(for r in $RUNS; do echo "$OUT/$r"; done) $FIT -o "$OUT/fit-all.json" | tee "$OUT/fit-all.log"
# Leave one run out.
echo "| left out | trajectory RMS (mm) | rest state RMS (mm) | linear baseline rest state (mm) |" > "$OUT/loro.md"
echo "|---|---|---|---|" >> "$OUT/loro.md"
for out in $RUNS; do
  rest=$(for r in $RUNS; do [ $r = $out ] || echo "$OUT/$r"; done)
  $P fit-motion $rest $FIT -o "$OUT/fit-without-$out.json" > "$OUT/fit-without-$out.log"
  $P validate --model "$OUT/fit-without-$out.json" "$OUT/$out" -o "$OUT/validate-$out" > "$OUT/validate-$out.log"
  tail -1 "$OUT/validate-$out.log" | python3 -c "
import json,sys; d=json.load(sys.stdin); b=d['baseline_final_rms_m']
print('| $out | %.3f | %.3f | %s |' % (1e3*d['trajectory_rms_m'], 1e3*d['final_rms_m'], '%.3f' % (1e3*b) if b is not None else '–'))" >> "$OUT/loro.md"
done
cat "$OUT/loro.md"
