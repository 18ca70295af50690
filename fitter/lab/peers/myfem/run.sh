#!/usr/bin/env bash
# The motion bench against MyFEM (the public code behind Real2Sim) on this machine, back to back (peers
# side by side, in one run): builds MyFEM's FEM, sensitivity analyses and objective from its public
# source (never committed: it goes under target/peers/) with the driver beside this script, runs the anchor
# problem of ANCHORS.md in MyFEM and then `palpate-lab bench motion`, and prints both JSON lines.
#
# usage: fitter/lab/peers/myfem/run.sh [REPEATS=3] [OPTIMISE=1] [MYFEM_SRC] [LBFGSPP_SRC]
#   The sources default to clones of https://github.com/david-hahn/MyFEM and https://github.com/yixuan/LBFGSpp (the
#   LBFGS MyFEM's examples use) under target/peers/. Needs g++, Eigen 3 and VTK 9 headers and libraries (Debian:
#   libeigen3-dev, libvtk9-dev).
# Run it alone on the machine (check `uptime`): the two codes share nothing but the clock. MyFEM runs with one
# OpenMP thread, as in ANCHORS.md; palpate's bench runs twice: on both cores where it can use them, then on one
# thread (RAYON_NUM_THREADS=1), the like-for-like figure.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
root=$(cd "$here/../../../.." && pwd)
repeats=${1:-3}
optimise=${2:-1}
peers=$root/target/peers
src=${3:-$peers/MyFEM}
lbfgs=${4:-$peers/LBFGSpp}
out=$peers/myfem
mkdir -p "$out/work"
[ -d "$src/src" ] || git clone --depth 1 https://github.com/david-hahn/MyFEM "$src"
[ -d "$lbfgs/include" ] || git clone --depth 1 https://github.com/yixuan/LBFGSpp "$lbfgs"
# The copy of MyFEM's sources the build compiles (made again only when the driver is rebuilt).
prepare_tree() {
rm -rf "$out/tree" && mkdir -p "$out/tree/Spectra" && cp -r "$src/src" "$out/tree/src"
# MyFEM was written against VTK 8, an old Spectra and MSVC. Adaptations to the copy (none changes the
# numerics of what the driver runs):
# - VTK 9 no longer stores cells as [n, i0, …] in one array, which MyFEM maps in place (`GetPointer() + 1`,
#   stride n + 1): the cells are exported in that legacy layout into an array kept beside the mesh and mapped
#   there (the driver's mesh never changes after loading);
# - MSVC binds temporaries to non-const references and reads `\` in include paths, and its headers bring in
#   <fstream>, <cfloat> and std's names: named locals, `/`, and a prelude included first (which also includes
#   LBFGSpp, named by MyFEM's types.h without an include);
# - the eigenmode viscosity model (not used here) calls Spectra's old interface: it compiles against stand-ins
#   that abort if ever called.
python3 - "$out/tree/src" <<'PY'
import re, sys
d = sys.argv[1]
def patch(name, f):
    p = d + "/" + name
    s = open(p).read()
    t = f(s)
    if t == s:
        sys.exit("patch of " + name + " did not apply")
    open(p, "w").write(t)
helper = """
#include <vtkCellArray.h>
#include <vtkIdTypeArray.h>
#include <map>
static vtkIdType* legacyCells(vtkCellArray* c){
	static std::map<vtkCellArray*, vtkSmartPointer<vtkIdTypeArray> > keep;
	vtkSmartPointer<vtkIdTypeArray>& a = keep[c];
	if( !a ) a = vtkSmartPointer<vtkIdTypeArray>::New();
	c->ExportLegacyFormat(a);
	return a->GetPointer(0);
}
"""
patch("LinearFEM.cpp", lambda s: s.replace('#include "LinearFEM.h"', '#include "LinearFEM.h"' + helper, 1)
      .replace("mesh->GetCells()->GetPointer()+1", "legacyCells(mesh->GetCells())+1")
      .replace("meshBoundary->GetCells()->GetPointer()+1", "legacyCells(meshBoundary->GetCells())+1"))
patch("DifferentiableSpline.cpp", lambda s: re.sub(r"#include <([^>]*)>", lambda m: "#include <" + m.group(1).replace("\\", "/") + ">", s))
patch("ViscousMaterialParameterHandler.cpp", lambda s: s.replace(
    "fem.computeVelocityGradient(dv, k, fem.getVectorVelocities());",
    "{ VectXMap vv = fem.getVectorVelocities(); fem.computeVelocityGradient(dv, k, vv); }"))
patch("ElasticMaterialParameterHandler.cpp", lambda s: s.replace(
    "ConsistentInertiaDerivativeAssemblyOp(Eigen::MatrixXd())",
    "ConsistentInertiaDerivativeAssemblyOp(*new Eigen::MatrixXd())"))
PY
cat > "$out/tree/src/prelude.h" <<'H'
#include <cfloat>
#include <cmath>
#include <fstream>
#include <iostream>
#include <LBFGS.h>
using namespace std;
H
printf '#pragma once\n' > "$out/tree/Spectra/SymEigsSolver.h"
cat > "$out/tree/Spectra/SymGEigsSolver.h" <<'H'
#pragma once
#include <cstdlib>
#include <Eigen/Dense>
namespace Spectra {
enum { SMALLEST_MAGN, GEIGS_REGULAR_INVERSE };
template <class S, int U, int F, class I> struct SparseSymMatProd { template <class M> SparseSymMatProd(const M&) {} int cols() const { return 0; } };
template <class S, int U, int F, class I> struct SparseRegularInverse { template <class M> SparseRegularInverse(const M&) {} };
template <class S, int R, class K, class M, int G> struct SymGEigsSolver {
    SymGEigsSolver(K*, M*, int, int) { std::abort(); }
    void init() {}
    int compute() { return 0; }
    Eigen::VectorXd eigenvalues() const { return {}; }
    Eigen::MatrixXd eigenvectors() const { return {}; }
};
}
H
}
vtk=$(ls -d /usr/include/vtk-9* | head -1)
# Every VTK library but the language bindings; the linker keeps those the objects need.
vtklibs=$(ls /usr/lib/x86_64-linux-gnu/libvtk*-9*.so | grep -v -E "Python|Java|MPI|mpi|Web|Wrapping" | tr '\n' ' ')
# The sources the driver needs: the FEM and its mesh reader, materials, both sensitivity analyses and their
# parameter handlers, the boundary objectives (and what they reference).
cpp=()
for f in LinearFEM ElmerReader Materials AdjointSensitivity DirectSensitivity BoundaryFieldObjectiveFunction \
  TemporalInterpolationField DifferentiableSpline ElasticMaterialParameterHandler ViscousMaterialParameterHandler \
  InitialConditionParameterHandler ContactFEM EigenmodeViscosityModel; do
  cpp+=("$out/tree/src/$f.cpp")
done
if [ ! -x "$out/driver" ] || [ "$here/driver.cpp" -nt "$out/driver" ]; then
  prepare_tree
  echo "building MyFEM and the driver (g++ -O3 -march=x86-64-v3 -DNDEBUG -fopenmp)" >&2
  g++ -std=c++14 -O3 -march=x86-64-v3 -DNDEBUG -D_USE_MATH_DEFINES -fopenmp -w -include "$out/tree/src/prelude.h" \
    -I"$out/tree/src" -I/usr/include/eigen3 -I"$vtk" -I"$lbfgs/include" \
    "${cpp[@]}" "$here/driver.cpp" -o "$out/driver" -Wl,--as-needed $vtklibs
fi
cd "$root"
cargo build --release -q -p palpate-lab
echo "load before: $(uptime)" >&2
# MyFEM reports every Newton iteration on stdout: kept in $out/driver.log, its JSON line printed.
OMP_NUM_THREADS=1 "$out/driver" "$out/work" "$repeats" "$optimise" > "$out/driver.log"
grep '^{' "$out/driver.log"
flags=()
[ "$optimise" = 1 ] || flags=(--no-optimize)
"$root/target/release/palpate-lab" bench motion "${flags[@]}" | tail -1
RAYON_NUM_THREADS=1 "$root/target/release/palpate-lab" bench motion "${flags[@]}" | tail -1
echo "load after: $(uptime)" >&2
