// The MyFEM side of `palpate-lab bench motion` (ANCHORS.md's anchor problem), built by run.sh against MyFEM's
// public source (never committed). A 3 × 22 × 3 cm bar of 1 cm cubes, six tetrahedra each (1,188 tets, 368 nodes),
// its y = 0 face moved as 1.5 cm·(1−cos 6πt) in x + 0.5 cm·(1−cos 10πt) in z, gravity −y, density 47 kg/m³,
// Neo-Hookean + power-law viscosity, BDF2 at Δt = 1/180 s for 90 steps from the elastostatic start, Newton to a
// squared residual below 1e-6 (the anchor's setting); 9 surface patches at palpate's nine marker places, their
// average displacement the observable. Prints one JSON line: the simulation + adjoint gradient and simulation +
// direct gradient times (median of `repeats`), and an LBFGS fit (m = 5, backtracking Wolfe, log-parameters) from
// (λ, μ, ν, h) = (20k, 10k, 6, 1.3) to the truth (10k, 20k, 12, 1.0), whose targets MyFEM simulates first.
//
// usage: driver <work dir> [repeats=3] [optimise=1]
#include "LinearFEM.h"
#include "Materials.h"
#include "AdjointSensitivity.h"
#include "DirectSensitivity.h"
#include "BoundaryFieldObjectiveFunction.h"
#include "ElasticMaterialParameterHandler.h"
#include "ViscousMaterialParameterHandler.h"
#include "LBFGS.h"
#include <vtkUnstructuredGrid.h>
#include <omp.h>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <exception>
#include <fstream>
#include <map>
#include <string>
#include <vector>
using namespace MyFEM;

static const unsigned BODY = 1, BASE = 1, SURFACE = 99;
static const int NX = 3, NY = 22, NZ = 3;
static const double H = 0.01, DT = 1.0 / 180.0;
static const unsigned STEPS = 90;

// Writes the bar as Elmer mesh files (mesh.header, .nodes, .elements, .boundary) into `dir`.
static void write_mesh(const std::string& dir) {
    auto id = [](int i, int j, int k) { return 1 + i + (NX + 1) * (j + (NY + 1) * k); };
    std::vector<std::array<double, 3>> x;
    for (int k = 0; k <= NZ; ++k)
        for (int j = 0; j <= NY; ++j)
            for (int i = 0; i <= NX; ++i) x.push_back({i * H, j * H, k * H});
    std::vector<std::array<int, 4>> tets;
    // Kuhn split of each cube along its main diagonal (0,0,0)–(1,1,1): six tets, conforming across cubes.
    const int perm[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
    for (int k = 0; k < NZ; ++k)
        for (int j = 0; j < NY; ++j)
            for (int i = 0; i < NX; ++i)
                for (auto& p : perm) {
                    int c[3] = {i, j, k};
                    std::array<int, 4> t;
                    t[0] = id(c[0], c[1], c[2]);
                    for (int s = 0; s < 3; ++s) {
                        c[p[s]] += 1;
                        t[s + 1] = id(c[0], c[1], c[2]);
                    }
                    // Positive orientation: swap two nodes when the signed volume is negative.
                    auto& a = x[t[0] - 1]; auto& b = x[t[1] - 1]; auto& cc = x[t[2] - 1]; auto& d = x[t[3] - 1];
                    double u[3], v[3], w[3];
                    for (int q = 0; q < 3; ++q) { u[q] = b[q] - a[q]; v[q] = cc[q] - a[q]; w[q] = d[q] - a[q]; }
                    double vol = u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0]) +
                                 u[2] * (v[0] * w[1] - v[1] * w[0]);
                    if (vol < 0) std::swap(t[2], t[3]);
                    tets.push_back(t);
                }
    // Boundary faces: faces of exactly one tet.
    std::map<std::array<int, 3>, std::pair<int, std::array<int, 3>>> faces;
    for (size_t e = 0; e < tets.size(); ++e) {
        const int fi[4][3] = {{0, 1, 2}, {0, 1, 3}, {0, 2, 3}, {1, 2, 3}};
        for (auto& f : fi) {
            std::array<int, 3> n = {tets[e][f[0]], tets[e][f[1]], tets[e][f[2]]}, key = n;
            std::sort(key.begin(), key.end());
            auto it = faces.find(key);
            if (it == faces.end()) faces[key] = {(int)e + 1, n};
            else faces.erase(it);
        }
    }
    // palpate's nine marker places (scenario::nine_markers): three heights, on the x = 0, x = 3 cm and z = 3 cm faces.
    std::vector<std::array<double, 3>> markers;
    for (int k = 1; k <= 3; ++k) {
        double y = NY * H * k / 3.0;
        markers.push_back({0.0, y, NZ * H / 2});
        markers.push_back({NX * H, y, NZ * H / 2});
        markers.push_back({NX * H / 2, y, NZ * H});
    }
    std::ofstream nodes(dir + "/mesh.nodes"), elems(dir + "/mesh.elements"), bnd(dir + "/mesh.boundary");
    nodes.precision(17);
    for (size_t n = 0; n < x.size(); ++n) nodes << n + 1 << " -1 " << x[n][0] << " " << x[n][1] << " " << x[n][2] << "\n";
    for (size_t e = 0; e < tets.size(); ++e)
        elems << e + 1 << " " << BODY << " 504 " << tets[e][0] << " " << tets[e][1] << " " << tets[e][2] << " " << tets[e][3] << "\n";
    int b = 0;
    for (auto& kv : faces) {
        auto& n = kv.second.second;
        double c[3] = {0, 0, 0};
        for (int q = 0; q < 3; ++q) for (int s = 0; s < 3; ++s) c[s] += x[n[q] - 1][s] / 3.0;
        unsigned bid = SURFACE;
        if (c[1] < 1e-9) bid = BASE;
        for (size_t m = 0; m < markers.size(); ++m) {
            double d2 = 0;
            for (int s = 0; s < 3; ++s) d2 += (c[s] - markers[m][s]) * (c[s] - markers[m][s]);
            // The patch: the surface triangles whose centroid lies within 7 mm of the marker place.
            if (d2 < 0.007 * 0.007 && bid == SURFACE) bid = 2 + m;
        }
        bnd << ++b << " " << bid << " " << kv.second.first << " 0 303 " << n[0] << " " << n[1] << " " << n[2] << "\n";
    }
    std::ofstream hdr(dir + "/mesh.header");
    hdr << x.size() << " " << tets.size() << " " << b << "\n2\n504 " << tets.size() << "\n303 " << b << "\n";
}

struct Base : VectorField {
    void eval(Eigen::Vector3d& p, const Eigen::Vector3d& x0, const Eigen::Vector3d&, double t) const override {
        p = x0 + 0.015 * (1.0 - cos(6.0 * M_PI * t)) * Eigen::Vector3d::UnitX() +
            0.005 * (1.0 - cos(10.0 * M_PI * t)) * Eigen::Vector3d::UnitZ();
    }
};
struct Gravity : VectorField {
    void eval(Eigen::Vector3d& g, const Eigen::Vector3d&, const Eigen::Vector3d&, double) const override {
        g = -9.81 * Eigen::Vector3d::UnitY();
    }
};
// A recorded patch displacement, linear in time between the steps.
struct Recorded : VectorField {
    std::vector<double> t;
    std::vector<Eigen::Vector3d> u;
    void eval(Eigen::Vector3d& p, const Eigen::Vector3d&, const Eigen::Vector3d&, double s) const override {
        if (t.empty()) { p.setZero(); return; }
        if (s <= t.front()) { p = u.front(); return; }
        if (s >= t.back()) { p = u.back(); return; }
        size_t i = std::upper_bound(t.begin(), t.end(), s) - t.begin();
        double a = (s - t[i - 1]) / (t[i] - t[i - 1]);
        p = (1 - a) * u[i - 1] + a * u[i];
    }
};
// Records every patch's average displacement at every step (the truth run).
struct Recorder : ObjectiveFunction {
    std::vector<Recorded>* out;
    double evaluate(LinearFEM& fem, Eigen::VectorXd& px, Eigen::VectorXd& pv, Eigen::VectorXd& pf,
                    Eigen::VectorXd& pq) override {
        px.resize(fem.getVectorDeformedCoords().size()); px.setZero();
        pv.resize(px.size()); pv.setZero(); pf.resize(px.size()); pf.setZero(); pq.resize(0);
        for (size_t m = 0; m < out->size(); ++m) {
            Eigen::Vector3d u;
            fem.computeAverageDisplacementOfBoundary(2 + m, u);
            (*out)[m].t.push_back(fem.simTime);
            (*out)[m].u.push_back(u);
        }
        return 0.0;
    }
};

static void set_material(LinearFEM& fem, double lambda, double mu, double nu, double h) {
    fem.initializeMaterialModel(BODY, LinearFEM::ISOTROPIC_NEOHOOKEAN, lambda, mu, 47.0);
    vtkSmartPointer<PowerLawViscosityModel> visc = vtkSmartPointer<PowerLawViscosityModel>::New();
    Eigen::VectorXd vp(visc->getNumberOfParameters());
    vp.setZero();
    visc->setViscosity(vp.data(), nu);
    visc->setPowerLawH(vp.data(), h);
    fem.initializeViscosityModel(BODY, visc, vp.data());
}

static double median(std::vector<double> v) { std::sort(v.begin(), v.end()); return v[v.size() / 2]; }

int main(int argc, char* argv[]) {
    if (argc < 2) { fprintf(stderr, "usage: driver <work dir> [repeats] [optimise]\n"); return 2; }
    std::string dir = argv[1];
    int repeats = argc > 2 ? atoi(argv[2]) : 3;
    bool optimise = argc > 3 ? atoi(argv[3]) != 0 : true;
    write_mesh(dir);
    const double eps = 1e-6;
    Base base; Gravity g;
    LinearFEM fem;
    if (fem.loadMeshFromElmerFiles(dir + "/mesh") < 0) { fprintf(stderr, "cannot read %s/mesh.*\n", dir.c_str()); return 1; }
    fem.useBDF2 = true;
    fem.setBoundaryCondition(BASE, base);
    fem.setExternalAcceleration(BODY, g);
    set_material(fem, 1e4, 2e4, 12.0, 1.0);

    // The truth run: it records the nine patches' displacements, the targets of the fit.
    std::vector<Recorded> targets(9);
    Recorder rec; rec.out = &targets;
    GlobalElasticMaterialParameterHandler elastic(BODY);
    GlobalPLViscosityMaterialParameterHandler viscous(BODY);
    CombinedParameterHandler q4(elastic, viscous);
    q4.useLogOfParams = true;
    {
        AdjointSensitivity truth(rec, q4, fem);
        truth.setupDynamicSim(DT, STEPS, true, "", NULL, eps);
        Eigen::VectorXd q(q4.getNumberOfParams(fem)), dq;
        q4.getCurrentParams(q, fem);
        truth(q, dq);
    }
    AverageBoundaryValueObjectiveFunction phi;
    phi.targetMode = AverageBoundaryValueObjectiveFunction::TARGET_DISPLACEMENT;
    for (size_t m = 0; m < targets.size(); ++m) phi.addTargetField(2 + m, targets[m]);

    // Timings at the start point.
    set_material(fem, 2e4, 1e4, 6.0, 1.3);
    Eigen::VectorXd q0(q4.getNumberOfParams(fem)), grad;
    q4.getCurrentParams(q0, fem);
    std::vector<double> adj, dir_;
    for (int r = 0; r < repeats; ++r) {
        {
            AdjointSensitivity a(phi, q4, fem);
            a.setupDynamicSim(DT, STEPS, true, "", NULL, eps);
            double t = omp_get_wtime();
            a(q0, grad);
            adj.push_back(omp_get_wtime() - t);
        }
        {
            DirectSensitivity d(phi, q4, fem);
            d.setupDynamicSim(DT, STEPS, true, "", NULL, eps);
            double t = omp_get_wtime();
            d(q0, grad);
            dir_.push_back(omp_get_wtime() - t);
        }
    }
    // MyFEM reports on stdout as it goes: the JSON line is assembled here and printed whole at the end.
    char json[1024];
    int len = snprintf(json, sizeof json,
                       "{\"peer\":\"MyFEM\",\"tets\":%u,\"nodes\":%u,\"steps\":%u,\"threads\":%d,"
                       "\"adjoint_s\":%.4f,\"direct_s\":%.4f,\"adjoint_runs_s\":[",
                       fem.getNumberOfElems(), fem.getNumberOfNodes(), STEPS, omp_get_max_threads(), median(adj),
                       median(dir_));
    for (size_t r = 0; r < adj.size(); ++r)
        len += snprintf(json + len, sizeof json - len, "%s%.4f", r ? "," : "", adj[r]);
    len += snprintf(json + len, sizeof json - len, "]");
    if (optimise) {
        set_material(fem, 2e4, 1e4, 6.0, 1.3);
        AdjointSensitivity a(phi, q4, fem);
        a.setupDynamicSim(DT, STEPS, true, "", NULL, eps);
        LBFGSpp::LBFGSParam<double> o;
        o.m = 5;
        o.linesearch = LBFGSpp::LBFGS_LINESEARCH_BACKTRACKING_WOLFE;
        // MyFEM's own examples' stop (main.cpp): on the objective's relative change over one iteration (1e-12),
        // not on the gradient's size.
        o.epsilon = 1e-20;
        o.epsilon_rel = 0.0;
        o.past = 1;
        o.delta = 1e-12;
        o.max_iterations = 150;
        LBFGSpp::LBFGSSolver<double, LBFGSpp::LineSearchBacktracking> solver(o);
        Eigen::VectorXd q = q0;
        double fx = 0;
        a.resetEvalCounter();
        double t = omp_get_wtime();
        int it = -1;
        try {
            it = solver.minimize(a, q, fx);
        } catch (const std::exception& e) {
            // LBFGSpp throws when its line search fails; the figures up to there are still reported.
            fprintf(stderr, "LBFGS stopped: %s\n", e.what());
        }
        double secs = omp_get_wtime() - t;
        len += snprintf(json + len, sizeof json - len,
                        ",\"optimisation_s\":%.3f,\"iterations\":%d,\"evaluations\":%u,\"phi\":%.6e,"
                        "\"q\":[%.6g,%.6g,%.6g,%.6g]",
                        secs, it, a.getEvalCounter(), fx, exp(q[0]), exp(q[1]), exp(q[2]), exp(q[3]));
    }
    printf("\n%s}\n", json);
    return 0;
}
