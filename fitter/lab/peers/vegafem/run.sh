#!/usr/bin/env bash
# The runtime bench against VegaFEM on this machine, back to back (peers side by side, in one
# run): builds VegaFEM's corotational linear FEM + CG from its public source (never committed: it goes
# under target/peers/), exports palpate's bench problem (`palpate-lab bench runtime --export-peer`), runs
# VegaFEM's solve of it and then palpate's bench of the same problem, and prints both JSON lines.
#
# usage: fitter/lab/peers/vegafem/run.sh [TETS=5000] [TICKS=1000] [RULE=lumped|consistent] [VEGA_SRC]
#   VEGA_SRC: a checkout of VegaFEM 4.0 with its `libraries/` (default: cloned from
#   https://github.com/dyollb/VegaFEM into target/peers/VegaFEM). Needs g++ and git.
# Run it alone on the machine (check `uptime`): the two codes share nothing but the clock.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../../../.." && pwd)
tets=${1:-5000}
ticks=${2:-1000}
rule=${3:-lumped}
src=${4:-$root/target/peers/VegaFEM}
out=$root/target/peers/vegafem
mkdir -p "$out"
if [ ! -d "$src/libraries" ]; then
  git clone --depth 1 https://github.com/dyollb/VegaFEM "$src"
fi
L=$src/libraries
# The libraries the corotational solve needs, with the same flags as palpate's host build (AVX2 + FMA).
cpp=(
  "$L/corotationalLinearFEM/corotationalLinearFEM.cpp"
  "$L/volumetricMesh/volumetricMesh.cpp" "$L/volumetricMesh/tetMesh.cpp" "$L/volumetricMesh/cubicMesh.cpp"
  "$L/volumetricMesh/volumetricMeshENuMaterial.cpp" "$L/volumetricMesh/volumetricMeshMooneyRivlinMaterial.cpp"
  "$L/volumetricMesh/volumetricMeshOrthotropicMaterial.cpp" "$L/volumetricMesh/volumetricMeshParser.cpp"
  "$L/volumetricMesh/generateMassMatrix.cpp"
  "$L/sparseMatrix/sparseMatrix.cpp" "$L/sparseSolver/CGSolver.cpp" "$L/sparseSolver/linearSolver.cpp"
  "$L/polarDecomposition/polarDecomposition.cpp"
  "$L/minivector/mat3d.cpp" "$L/minivector/vec3d.cpp" "$L/minivector/eig3.cpp" "$L/minivector/vec3i.cpp"
  "$L/minivector/vec4i.cpp" "$L/minivector/vec2d.cpp"
  "$L/mesh/geometryQuery.cpp" "$L/mesh/boundingBox.cpp" "$L/constrainedDOFs/constrainedDOFs.cpp"
)
# VegaFEM's CMake writes vega-config.h; without TBB, MKL, PARDISO or GLUT it says nothing. Sections are
# collected so the bounding box's OpenGL drawing (never called) needs no GL library. C++14: the
# library's own `clamp` is ambiguous with C++17's std::clamp.
mkdir -p "$out/config"
printf '#pragma once\n' > "$out/config/vega-config.h"
inc=("-I$out/config")
for d in "$L"/*/; do inc+=("-I$d"); done
if [ ! -x "$out/driver" ] || [ "$here/driver.cpp" -nt "$out/driver" ]; then
  echo "building VegaFEM's corotational FEM + CG and the driver (g++ -O3 -march=x86-64-v3 -DNDEBUG)" >&2
  g++ -std=c++14 -O3 -march=x86-64-v3 -DNDEBUG -w -ffunction-sections -Wl,--gc-sections \
    "${inc[@]}" "${cpp[@]}" "$here/driver.cpp" -o "$out/driver"
fi
cd "$root"
cargo build --release -q -p palpate-lab
lab=$root/target/release/palpate-lab
echo "load before: $(uptime)" >&2
"$lab" bench runtime --tets "$tets" --ticks "$ticks" --rule "$rule" --export-peer "$out/problem-$tets-$rule" >&2
"$out/driver" "$out/problem-$tets-$rule" 1 1e-4
"$lab" bench runtime --tets "$tets" --ticks "$ticks" --rule "$rule" --gradient-only --direct-ticks 5 | tail -1
echo "load after: $(uptime)" >&2
