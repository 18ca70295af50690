"""Independent motion-dataset generator (stretch goal): a horizontally clamped cylinder under gravity.

    python independent_motion.py -o OUT [--seed 1] [--duration 1.2] [--fps 100] [--check]

The classic Real2Sim set-up: a cylinder 20 cm long, clamped at x = 0 (physical group "clamp"), sagging
~25 mm under gravity (-z). It starts from elastostatic equilibrium under gravity, then the clamp is
moved (a smooth up-and-sideways translation of 1-3 cm over 0.2-0.4 s, then held) and the cylinder
swings and rings down. Writes palpate's motion dataset (docs/motion-dataset.md: dataset.toml, mesh.msh,
markers.csv, trajectories.csv, clamps.csv) + truth.json.

`--clamp-compliance ELL` (metres) holds the clamped face by springs instead of rigidly: each clamped node
is tied to where the clamp puts it by k_n = E/ELL across the face and k_t = mu/ELL along it (Pa/m, per
area; the face's area shared equally by its nodes), the give of a layer ELL thick of the body's own
material. The dataset still declares the face clamped, as a user who does not know the clamp gives would.

`--gravity-tilt DEG` turns the truth's gravity by DEG degrees about the cylinder's axis: the object mounted
turned, or the lab's vertical registered wrong. The dataset still declares gravity along -z.

Truth (own code, truthfem.py + this file): compressible Neo-Hookean (ln J form) on a Gmsh P1 mesh, lumped
mass, Kelvin-Voigt damping with second Piola-Kirchhoff viscous stress S_v = 2 eta sym(F^T Fdot) (objective:
a rigid rotation dissipates nothing), implicit BDF2 in time (implicit Euler for the first step), modified Newton
with a general sparse LU kept while it contracts the residual fourfold an iteration (the viscous tangent is
not symmetric) and a residual-norm backtracking line search on a fresh factor's step.
`--check` runs a finite-difference test of the viscous stress tangent first.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import time

import gmsh
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

import truthfem as tf

L_CYL = 0.20


def mesh_cylinder(R, h, seed, algo3d, out_msh=None):
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("cyl")
        v = gmsh.model.occ.addCylinder(0, 0, 0, L_CYL, 0, 0, R)
        gmsh.model.occ.synchronize()
        groups = {"clamp": [], "free_end": [], "side": []}
        for dim, tag in gmsh.model.getEntities(2):
            x = gmsh.model.occ.getCenterOfMass(dim, tag)[0]
            groups["clamp" if x < 1e-7 else "free_end" if x > L_CYL - 1e-7 else "side"].append(tag)
        for k, t in groups.items():
            gmsh.model.addPhysicalGroup(2, t, name=k)
        gmsh.model.addPhysicalGroup(3, [v], name="body")
        gmsh.option.setNumber("Mesh.MeshSizeMin", h)
        gmsh.option.setNumber("Mesh.MeshSizeMax", h)
        gmsh.option.setNumber("Mesh.RandomSeed", seed)
        gmsh.option.setNumber("Mesh.Algorithm3D", algo3d)
        gmsh.model.mesh.generate(3)
        tags, coords, _ = gmsh.model.mesh.getNodes()
        X = coords.reshape(-1, 3)
        index = {int(t): i for i, t in enumerate(tags)}
        _, en = gmsh.model.mesh.getElementsByType(4)
        T = np.vectorize(index.__getitem__)(en.reshape(-1, 4).astype(np.int64))
        clamp = set()
        for ent in groups["clamp"]:
            _, _, nodes = gmsh.model.mesh.getElements(2, ent)
            clamp |= {index[int(n)] for n in np.concatenate(nodes)}
        if out_msh:
            gmsh.option.setNumber("Mesh.MshFileVersion", 4.1)
            gmsh.option.setNumber("Mesh.Binary", 0)
            gmsh.write(out_msh)
        return X, T, np.array(sorted(clamp))
    finally:
        gmsh.finalize()


def viscous(F, Fdot, eta, c, tangent=True):
    """Kelvin-Voigt: P_v = F S_v, S_v = 2 eta sym(F^T Fdot); tangent dP_v/dF when Fdot = c F + const
    (None without `tangent`)."""
    E = 0.5 * (np.einsum("eaM,eaJ->eMJ", F, Fdot) + np.einsum("eaM,eaJ->eMJ", Fdot, F))
    S = 2 * eta[:, None, None] * E
    P = np.einsum("eiM,eMJ->eiJ", F, S)
    if not tangent:
        return P, None
    # dE_MJ/dF_kL = 1/2 (d_ML Fdot_kJ + c F_kM d_JL + c d_ML F_kJ + Fdot_kM d_JL)
    #             = 1/2 (d_ML G_kJ + d_JL G_kM),  G = Fdot + c F
    # (the Kronecker deltas written as slice assignments: an einsum with the identity costs more)
    G = 0.5 * (Fdot + c * F)
    dE = np.zeros((len(F), 3, 3, 3, 3))
    for d in range(3):
        dE[:, d, :, :, d] += G.transpose(0, 2, 1)  # d_ML G_kJ at M = L = d: (e, J, k)
        dE[:, :, d, :, d] += G.transpose(0, 2, 1)  # d_JL G_kM at J = L = d: (e, M, k)
    FdE = (F @ dE.reshape(len(F), 3, 27)).reshape(dE.shape)  # F_iM dE_MJkL, a batched product
    A = 2 * eta[:, None, None, None, None] * FdE
    for d in range(3):
        A[:, d, :, d, :] += S.transpose(0, 2, 1)  # d_ik S_LJ at i = k = d: (e, J, L)
    return P, A


def check_viscous_tangent(rng):
    F = np.eye(3)[None] + 0.2 * rng.standard_normal((4, 3, 3))
    F0 = np.eye(3)[None] + 0.2 * rng.standard_normal((4, 3, 3))
    c, eta = 50.0, np.full(4, 3.0)
    Fd = lambda F: c * (F - F0)
    P, A = viscous(F, Fd(F), eta, c)
    h = 1e-6
    Afd = np.zeros_like(A)
    for k in range(3):
        for L in range(3):
            d = np.zeros((3, 3))
            d[k, L] = h
            Afd[..., k, L] = (viscous(F + d, Fd(F + d), eta, c)[0] - viscous(F - d, Fd(F - d), eta, c)[0]) / (2 * h)
    # objectivity: a spin W F with Fdot = W F dissipates nothing
    W = np.array([[0, -1.0, 0], [1.0, 0, 0], [0, 0, 0]])
    Pspin, _ = viscous(F, np.einsum("ij,ejk->eik", W, F), eta, c)
    return {"viscous_tangent_vs_fd": float(np.abs(A - Afd).max() / np.abs(A).max()),
            "spin_viscous_stress": float(np.abs(Pspin).max())}


class Dynamic:
    def __init__(self, X, T, E, nu, rho, eta, clamp, g, spring=None):
        """`spring`: per-dof stiffness (N/m) tying the clamped nodes to the clamp; None: held rigidly."""
        self.body = tf.Body(X, T, tf.Material.from_E_nu(E, nu, len(T)))
        self.eta = np.full(len(self.body.T), float(eta))
        n = len(X)
        w = np.zeros(n)
        np.add.at(w, self.body.T.ravel(), np.repeat(self.body.V / 4, 4))
        self.m = np.repeat(rho * w, 3)
        self.fg = np.zeros(3 * n)
        self.fg.reshape(-1, 3)[:] = np.outer(rho * w, g)
        self.clamp = clamp
        self.spring = spring
        fixed = np.zeros(3 * n, bool)
        if spring is None:
            fixed[(3 * clamp[:, None] + np.arange(3)).ravel()] = True
        self.free = np.flatnonzero(~fixed)
        self.cdofs = np.flatnonzero(fixed)
        self._lu, self._lu_key = None, None  # the kept Newton factor and the (cu, cv) it was made with

    def forces(self, u, Fdot_fn, c, tangent=True):
        """Internal forces f(u) and, with `tangent`, their Jacobian K (None without)."""
        b = self.body
        F = b.F(u)
        if (np.linalg.det(F) <= 0).any():
            raise tf.SolveError("inverted element")
        P, A = tf.stress_tangent(F, b.mat, tangent)
        Pv, Av = viscous(F, Fdot_fn(F), self.eta, c, tangent)
        P = P + Pv
        fe = b.V[:, None, None] * np.einsum("eiJ,eaJ->eai", P, b.B)
        f = np.zeros(3 * b.n)
        np.add.at(f, b._dof.ravel(), fe.reshape(-1))
        if not tangent:
            return f, None
        A = A + Av
        # K_e[a,i,b,k] = V B[a,J] A[i,J,k,L] B[b,L], contracted one operand at a time as batched
        # matrix products (A·Bᵀ, then B·(A·Bᵀ)): the same sums grouped otherwise (round-off only),
        # for a fifteenth of a three-operand einsum's time.
        ne = len(b.T)
        AB = (A.reshape(ne, 27, 3) @ b.B.transpose(0, 2, 1)).reshape(ne, 3, 3, 3, 4)  # e i J k b
        Ke = (b.B @ AB.transpose(0, 2, 1, 4, 3).reshape(ne, 3, 36)).reshape(ne, 4, 3, 4, 3)
        return f, self._assemble(b.V[:, None, None, None, None] * Ke)

    def _assemble(self, Ke):
        """The global tangent from the element blocks: the CSR pattern of the (row, col) pairs made
        once, each call summing the blocks into it."""
        b = self.body
        if not hasattr(self, "_csr"):
            key = b._rows.astype(np.int64) * (3 * b.n) + b._cols
            uniq, inv = np.unique(key, return_inverse=True)
            rows, cols = uniq // (3 * b.n), uniq % (3 * b.n)
            indptr = np.zeros(3 * b.n + 1, np.int64)
            np.add.at(indptr, rows + 1, 1)
            self._csr = (inv, cols, np.cumsum(indptr), len(uniq))
        inv, cols, indptr, nnz = self._csr
        data = np.bincount(inv, weights=Ke.ravel(), minlength=nnz)
        return sp.csr_matrix((data, cols, indptr), shape=(3 * b.n, 3 * b.n))

    def step(self, u_hist, v_hist, uc, dt, bdf2):
        """One implicit step; u_hist = [u_n, u_{n-1}], v_hist likewise; uc = clamp displacement (3,)."""
        b = self.body
        if bdf2:
            cu, cv = 1.5 / dt, 1.5 / dt
            u_part = (-4 * u_hist[0] + u_hist[1]) / (2 * dt)
            v_part = (-4 * v_hist[0] + v_hist[1]) / (2 * dt)
        else:
            cu = cv = 1.0 / dt
            u_part, v_part = -u_hist[0] / dt, -v_hist[0] / dt
        u = u_hist[0] + dt * v_hist[0]  # predictor
        u.reshape(-1, 3)[self.clamp] = uc
        anchor = np.zeros_like(u)
        anchor.reshape(-1, 3)[self.clamp] = uc
        # F-dot = cu F + (terms of the history): F(u) is affine in u
        def Fdot_fn(F, up=u_part):
            Fp = np.einsum("eai,eaJ->eiJ", up.reshape(-1, 3)[b.T], b.B)  # grad of the history part
            return cu * (F - np.eye(3)[None]) + Fp  # grad v, v = cu u + u_part
        def residual(u, tangent=True):
            v = cu * u + u_part
            a = cv * v + v_part
            f, K = self.forces(u, Fdot_fn, cu, tangent)
            r = self.m * a + f - self.fg
            if self.spring is not None:
                r = r + self.spring * (u - anchor)
                if K is not None:
                    K = K + sp.diags(self.spring)
            return r, K

        def factor(u):
            _, K = residual(u)
            J = (K + sp.diags(self.m * cu * cv))[self.free][:, self.free].tocsc()
            return spla.splu(J, permc_spec="COLAMD")

        # Modified Newton: the LU of the step matrix is kept across iterations and steps while an
        # iteration with it cuts the residual fourfold, and made afresh at the current iterate where it
        # does not (or the step size changed); a fresh factor's step is Newton's, with the residual-norm
        # backtracking line search. The step ends at the same residual tolerance either way.
        tol = 1e-8 * max(np.linalg.norm(self.fg), 1e-12)
        r, _ = residual(u, tangent=False)
        for it in range(30):
            rn = np.linalg.norm(r[self.free])
            if rn <= tol:
                break
            fresh = self._lu is None or self._lu_key != (cu, cv)
            if fresh:
                self._lu, self._lu_key = factor(u), (cu, cv)
            du = self._lu.solve(-r[self.free])
            if not fresh:
                un = u.copy()
                un[self.free] += du
                try:
                    rr, _ = residual(un, tangent=False)
                    kept = np.linalg.norm(rr[self.free]) <= 0.25 * rn
                except tf.SolveError:
                    kept = False
                if kept:
                    u, r = un, rr
                    continue
                self._lu, self._lu_key = factor(u), (cu, cv)
                du = self._lu.solve(-r[self.free])
            alpha = 1.0
            while True:
                un = u.copy()
                un[self.free] += alpha * du
                try:
                    rr, _ = residual(un, tangent=False)
                    if np.linalg.norm(rr[self.free]) < (1 - 1e-4 * alpha) * rn or alpha < 1e-3:
                        break
                except tf.SolveError:
                    pass
                alpha *= 0.5
                if alpha < 1e-4:
                    raise tf.SolveError("line search failed in a time step")
            u, r = un, rr
        else:
            raise tf.SolveError("time step did not converge")
        v = cu * u + u_part
        return u, v, it


def clamp_path(t, amp, t0, t1):
    """Smooth (C2, quintic) ramp from 0 to amp between t0 and t1."""
    s = np.clip((t - t0) / (t1 - t0), 0, 1)
    return amp * (10 * s**3 - 15 * s**4 + 6 * s**5)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-o", "--out", required=True)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--duration", type=float, default=1.2)
    ap.add_argument("--fps", type=float, default=100.0)
    ap.add_argument("--substeps", type=int, default=8,
                    help="truth BDF2 steps per capture frame (1 = integrate at the capture rate, where BDF2's own "
                         "period error and numerical damping become part of the 'truth'; default 8)")
    ap.add_argument("--check", action="store_true")
    ap.add_argument("--damping-ratio", type=float, default=None, help="override the drawn damping ratio (0 = no Kelvin-Voigt damping)")
    ap.add_argument("--clamp-compliance", type=float, default=0.0, metavar="ELL",
                    help="hold the clamped face by springs of a layer ELL metres thick of the body's material (0 = rigid)")
    ap.add_argument("--gravity-tilt", type=float, default=0.0, metavar="DEG",
                    help="turn the truth's gravity by DEG degrees about the cylinder's axis (toward +y); the "
                         "dataset still declares (0, 0, -9.81)")
    a = ap.parse_args()
    t_start = time.time()
    rng = np.random.default_rng([a.seed, 44])
    checks = check_viscous_tangent(rng) if a.check else None
    if checks:
        print("checks:", checks)
    R = rng.uniform(0.010, 0.015)
    rho = rng.uniform(1000, 1200)
    nu = rng.uniform(0.3, 0.49)
    sag_target = rng.uniform(0.02, 0.03)
    # Euler-Bernoulli cantilever under its own weight: sag = rho g L^4 / (2 E R^2)
    E = rho * 9.81 * L_CYL**4 / (2 * R**2 * sag_target)
    mu = E / (2 * (1 + nu))
    # Kelvin-Voigt viscosity: damping ratio 1-5 % of the first bending mode (beam estimate)
    w1 = 1.875**2 * math.sqrt(E * R**2 / (4 * rho * L_CYL**4))
    zeta = rng.uniform(0.01, 0.05)
    if a.damping_ratio is not None:
        zeta = a.damping_ratio
    eta = 2 * zeta * E / w1 / 3  # KV on the axial strain rate: zeta = eta_ax w / (2E), eta_ax ~ 3 eta for nu ~ 0.5
    amp = np.array([0.0, rng.uniform(-0.02, 0.02), rng.uniform(0.01, 0.03)])
    t_ramp = rng.uniform(0.2, 0.4)
    sigma = rng.uniform(1e-4, 3e-4)
    os.makedirs(a.out, exist_ok=True)
    Xt, Tt, clamp_t = mesh_cylinder(R, R / 2.5, seed=int(rng.integers(1, 9999)), algo3d=1)
    Xd, Td, _ = mesh_cylinder(R, R / 1.6, seed=int(rng.integers(1, 9999)), algo3d=10, out_msh=os.path.join(a.out, "mesh.msh"))
    print(f"E={E:.4g} Pa nu={nu:.3f} rho={rho:.0f} R={R * 1e3:.1f} mm eta={eta:.3g} Pa s, truth {len(Tt)} tets, dataset {len(Td)} tets")
    tilt = math.radians(a.gravity_tilt)
    g = 9.81 * np.array([0.0, math.sin(tilt), -math.cos(tilt)])
    if a.gravity_tilt:
        print(f"gravity turned by {a.gravity_tilt:g} deg about the axis: {g.round(4).tolist()} m/s^2")
    spring = None
    if a.clamp_compliance > 0:
        area = math.pi * R**2 / len(clamp_t)
        spring = np.zeros(3 * len(Xt))
        k = spring.reshape(-1, 3)
        k[clamp_t, 0] = E / a.clamp_compliance * area
        k[clamp_t, 1:] = mu / a.clamp_compliance * area
        print(f"clamp held by springs: a layer {a.clamp_compliance * 1e3:.1f} mm thick of the body's material")
    dyn = Dynamic(Xt, Tt, E, nu, rho, eta, clamp_t, g, spring)
    # static start (the springs tie the clamped nodes to where they rest)
    prob = tf.Problem(dyn.body, spring=spring) if spring is not None else tf.Problem(dyn.body, fixed_nodes=clamp_t)
    u0, it0 = prob.solve(dyn.fg, steps=4)
    tip = np.argmax(Xt[:, 0] - 10 * np.abs(Xt[:, 1]) - 10 * np.abs(Xt[:, 2]))
    sag = -u0.reshape(-1, 3)[tip, 2]
    print(f"static sag at the tip {sag * 1e3:.1f} mm ({it0} Newton iterations)")
    # markers: on the side surface, along the top and the side, plus the free end
    nm = int(rng.integers(16, 33))
    xs = rng.uniform(0.02, L_CYL, nm)
    th = rng.uniform(-math.pi / 2, math.pi / 2, nm)  # visible half (camera at +y... any)
    P = np.stack([xs, R * np.sin(th) * 0.999, R * np.cos(th) * 0.999], axis=1)
    # embed the markers in the truth tets (barycentric; nearest tet centroid fallback)
    cent = Xt[Tt].mean(axis=1)
    bary_t, tet_t = [], []
    for p in P:
        cand = np.argsort(np.linalg.norm(cent - p, axis=1))[:40]
        best = None
        for e in cand:
            M = np.ones((4, 4))
            M[:3] = Xt[Tt[e]].T
            lam = np.linalg.solve(M, np.append(p, 1))
            if best is None or lam.min() > best[1].min():
                best = (e, lam)
        tet_t.append(best[0])
        bary_t.append(best[1])
    tet_t, bary_t = np.array(tet_t), np.array(bary_t)
    def markers(u):
        x = Xt + u.reshape(-1, 3)
        return np.einsum("mk,mki->mi", bary_t, x[Tt[tet_t]])
    dt = 1.0 / a.fps
    n_steps = int(round(a.duration / dt))
    hist_u, hist_v = [u0, u0], [np.zeros_like(u0), np.zeros_like(u0)]
    traj = [markers(u0)]
    clamps = [np.zeros(3)]
    iters = []
    # The truth is integrated finer than it is sampled: a capture samples a continuous motion, and
    # BDF2 at the capture rate (10 frames per period here) lengthens the period and damps the
    # ring-down by itself, which would make the integrator part of the "truth".
    sub = max(1, a.substeps)
    h = dt / sub
    for n in range(1, n_steps + 1):
        t = n * dt
        it = 0
        for j in range(1, sub + 1):
            ts = (n - 1) * dt + j * h
            uc = clamp_path(ts, amp, 0.05, 0.05 + t_ramp)
            u, v, itj = dyn.step(hist_u, hist_v, uc, h, bdf2=(n > 1 or j > 1))
            hist_u, hist_v = [u, hist_u[0]], [v, hist_v[0]]
            it = max(it, itj)
        traj.append(markers(u))
        clamps.append(uc)
        iters.append(it)
        if n % 20 == 0:
            print(f"  t={t:.2f} s tip z {1e3 * u.reshape(-1, 3)[tip, 2]:.1f} mm, Newton {it}, {time.time() - t_start:.0f} s", flush=True)
    traj = np.array(traj)
    rng_n = np.random.default_rng([a.seed, 55])
    noisy = traj + sigma * rng_n.standard_normal(traj.shape)
    drop = rng_n.uniform(size=traj.shape[:2]) < 0.03
    rest = P + sigma / math.sqrt(10) * rng_n.standard_normal(P.shape)
    with open(os.path.join(a.out, "markers.csv"), "w") as fh:
        fh.write("marker,x,y,z\n")
        for k, p in enumerate(rest):
            fh.write(f"m{k + 1},{p[0]:.9e},{p[1]:.9e},{p[2]:.9e}\n")
    with open(os.path.join(a.out, "trajectories.csv"), "w") as fh:
        fh.write("t,marker,x,y,z\n")
        for n in range(n_steps + 1):
            for k in range(nm):
                if not drop[n, k]:
                    x = noisy[n, k]
                    fh.write(f"{n * dt:.9f},m{k + 1},{x[0]:.9e},{x[1]:.9e},{x[2]:.9e}\n")
    with open(os.path.join(a.out, "clamps.csv"), "w") as fh:
        fh.write("t,clamp,ux,uy,uz\n")
        for n, c in enumerate(clamps):
            fh.write(f"{n * dt:.9f},clamp,{c[0]:.9e},{c[1]:.9e},{c[2]:.9e}\n")
    with open(os.path.join(a.out, "dataset.toml"), "w") as fh:
        fh.write(f'name = "indep-motion-s{a.seed}"\ndescription = "independent motion generator (tests/generators/independent_motion.py)"\n')
        fh.write(f'units = "SI"\nmesh = "mesh.msh"\ndt = {dt!r}\nsteps = {n_steps}\ndensity = {rho!r}\n')
        fh.write(f'gravity = [0.0, 0.0, -9.81]\nclamps = ["clamp"]\nstatic_start = true\nmarker_noise = {sigma!r}\n')
    truth = {"generator": "tests/generators/independent_motion.py", "seed": a.seed, "E_Pa": E, "nu": nu,
             "lambda_Pa": E * nu / ((1 + nu) * (1 - 2 * nu)), "mu_Pa": mu, "density": rho,
             "kelvin_voigt_eta_Pa_s": eta, "damping_ratio_target": zeta, "radius_m": R, "length_m": L_CYL,
             "static_tip_sag_m": float(sag), "clamp_amplitude_m": amp.tolist(), "clamp_ramp_s": [0.05, 0.05 + t_ramp],
             "clamp_compliance_layer_m": a.clamp_compliance,
             "gravity_truth_m_s2": g.tolist(), "gravity_tilt_deg": a.gravity_tilt,
             "marker_noise_m": sigma, "dt": dt, "steps": n_steps, "truth_substeps": sub, "markers": nm,
             "truth_tets": int(len(Tt)), "dataset_tets": int(len(Td)), "newton_iterations_per_step": iters,
             "checks": checks, "seconds": time.time() - t_start}
    with open(os.path.join(a.out, "truth.json"), "w") as fh:
        json.dump(truth, fh, indent=1)
    print(f"wrote {a.out} in {time.time() - t_start:.0f} s")


if __name__ == "__main__":
    main()
