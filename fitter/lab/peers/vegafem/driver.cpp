// palpate's runtime bench problem solved by VegaFEM: its corotational linear FEM (Mueller 2004 stiffness
// warping, warp = 1, or the exact corotational tangent, warp = 2) and its Jacobi-preconditioned CG, one
// warped solve per haptic tick warm-started from the previous tick, with palpate's stop rule
// ||r|| <= tol ||f_ext||. The problem (mesh, fixed nodes, the lumped rule's nodal forces of every tick)
// comes from `palpate-lab bench runtime --export-peer DIR`, so both codes solve the same ticks.
//
// This file is palpate's (a driver); VegaFEM itself is built from its public source by run.sh and is
// never part of the repository.
//
// usage: driver DIR [warp=1] [tol=1e-4] [settle=20]; prints one JSON line.

#include "CGSolver.h"
#include "corotationalLinearFEM.h"
#include "sparseMatrix.h"
#include "tetMesh.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

static double thread_cpu() {
  timespec t;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return t.tv_sec + 1e-9 * t.tv_nsec;
}

static double percentile(std::vector<double> v, double q) {
  std::sort(v.begin(), v.end());
  size_t i = (size_t)std::lround((v.size() - 1) * q);
  return v[std::min(i, v.size() - 1)];
}

int main(int argc, char **argv) {
  if (argc < 2) {
    std::fprintf(stderr, "usage: %s DIR [warp=1] [tol=1e-4] [settle=20]\n", argv[0]);
    return 2;
  }
  const std::string dir = argv[1];
  const int warp = argc > 2 ? std::atoi(argv[2]) : 1;
  const double tol = argc > 3 ? std::atof(argv[3]) : 1e-4;
  const int settle = argc > 4 ? std::atoi(argv[4]) : 20;

  TetMesh mesh((dir + "/block.veg").c_str(), VolumetricMesh::ASCII, 0);
  const int n = mesh.getNumVertices(), ndof = 3 * n;

  std::vector<int> fixed_dofs;
  {
    std::ifstream f(dir + "/fixed.txt");
    int i;
    while (f >> i)
      for (int c = 0; c < 3; c++) fixed_dofs.push_back(3 * i + c);
    std::sort(fixed_dofs.begin(), fixed_dofs.end());
  }
  std::vector<std::vector<std::pair<int, std::array<double, 3>>>> loads;
  {
    std::ifstream f(dir + "/loads.txt");
    std::string line;
    while (std::getline(f, line)) {
      std::istringstream s(line);
      int k, m;
      s >> k >> m;
      std::vector<std::pair<int, std::array<double, 3>>> row(m);
      for (auto &e : row) s >> e.first >> e.second[0] >> e.second[1] >> e.second[2];
      loads.push_back(row);
    }
  }
  if (loads.empty()) {
    std::fprintf(stderr, "%s/loads.txt: no ticks\n", dir.c_str());
    return 1;
  }

  CorotationalLinearFEM fem(&mesh);
  SparseMatrix *K;
  fem.GetStiffnessMatrixTopology(&K);
  SparseMatrix Kf(*K);
  Kf.RemoveRowsColumns((int)fixed_dofs.size(), fixed_dofs.data());
  Kf.BuildSuperMatrixIndices((int)fixed_dofs.size(), fixed_dofs.data(), K);
  std::vector<int> free_dof;
  for (int d = 0, j = 0; d < ndof; d++) {
    if (j < (int)fixed_dofs.size() && fixed_dofs[j] == d) {
      j++;
      continue;
    }
    free_dof.push_back(d);
  }
  const int nf = (int)free_dof.size();
  std::vector<double> u(ndof, 0.0), fint(ndof), fext(ndof), b(nf), du(nf);

  // One haptic tick: loads of tick k, the warped stiffness and forces at the current state, one
  // Jacobi-CG solve of K du = f_ext - f_int (skipped when the residual already meets the rule).
  auto tick = [&](int k) -> int {
    std::fill(fext.begin(), fext.end(), 0.0);
    for (auto &e : loads[k])
      for (int c = 0; c < 3; c++) fext[3 * e.first + c] = e.second[c];
    double energy = 0.0;
    fem.ComputeEnergyAndForceAndStiffnessMatrix(u.data(), &energy, fint.data(), K, warp);
    Kf.AssignSuperMatrix(*K);
    double fn = 0.0, bn = 0.0;
    for (int i = 0; i < nf; i++) {
      const int d = free_dof[i];
      b[i] = fext[d] - fint[d];
      fn += fext[d] * fext[d];
      bn += b[i] * b[i];
    }
    fn = std::sqrt(fn);
    bn = std::sqrt(bn);
    if (bn <= tol * fn) return 0;
    std::fill(du.begin(), du.end(), 0.0);
    CGSolver cg(&Kf);
    int it = cg.SolveLinearSystemWithJacobiPreconditioner(du.data(), b.data(), tol * fn / bn, 100000, 0);
    for (int i = 0; i < nf; i++) u[free_dof[i]] += du[i];
    return std::abs(it);
  };

  for (int s = 0; s < settle; s++) tick(0);
  const int ticks = (int)loads.size();
  std::vector<double> wall(ticks), cpu(ticks), iters(ticks);
  for (int k = 0; k < ticks; k++) {
    const double c0 = thread_cpu();
    const auto t0 = std::chrono::steady_clock::now();
    iters[k] = tick(k);
    wall[k] = std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count();
    cpu[k] = (thread_cpu() - c0) * 1e6;
  }
  double mean_it = 0.0, max_it = 0.0;
  for (double i : iters) {
    mean_it += i / ticks;
    max_it = std::max(max_it, i);
  }
  double tip = 0.0;
  for (int d = 2; d < ndof; d += 3) tip = std::min(tip, u[d]);
  std::printf(
      "{\"peer\": \"VegaFEM CorotationalLinearFEM warp=%d + CGSolver Jacobi\", \"tets\": %d, \"free_dofs\": %d, "
      "\"ticks\": %d, \"tolerance\": %g, \"wall_p50_us\": %.1f, \"wall_p99_us\": %.1f, \"wall_max_us\": %.1f, "
      "\"cpu_p50_us\": %.1f, \"cpu_p99_us\": %.1f, \"cpu_max_us\": %.1f, \"cg_iterations_mean\": %.2f, "
      "\"cg_iterations_max\": %.0f, \"min_uz_m\": %.6e}\n",
      warp, mesh.getNumElements(), nf, ticks, tol, percentile(wall, 0.5), percentile(wall, 0.99),
      percentile(wall, 1.0), percentile(cpu, 0.5), percentile(cpu, 0.99), percentile(cpu, 1.0), mean_it, max_it,
      tip);
  return 0;
}
