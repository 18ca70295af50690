"""Checks of the independent truth solver (truthfem.py). Run:

    python check_truth_solver.py [-o check.json]

1. Material point: P against central differences of W, and A = dP/dF against central differences of
   P, at random deformation gradients, for Neo-Hookean and Neo-Hookean + Yeoh c2.
2. Assembled internal force against central differences of the total strain energy, and the assembled
   tangent against central differences of the internal force, on a small random mesh at a random
   finite displacement (directional derivatives along random directions).
3. The tangent at u = 0 against a linear-elasticity stiffness assembled independently (Voigt B^T D B).
4. A bar in uniaxial tension and compression (symmetry planes, dead traction on the end face):
   a) at small load against the analytic linear solution u_x = s x / E, u_y = -nu s y / E;
   b) at 20 % stretch / 15 % compression against the analytic homogeneous Neo-Hookean(+Yeoh) solution
      (the 2 x 2 equations of uniaxial stress solved with scipy on the scalar energy written out
      separately), which P1 elements represent exactly.
5. A probed block: the Newton solution at load t f against t times the linear solution, for
   t -> 0 (the difference must fall as t^2, i.e. relative difference proportional to t).
Exits non-zero if a check fails.
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np
import scipy.optimize as so

import shapes
import truthfem as tf


def check_material(rng):
    out = {}
    for label, c2 in [("neo-hookean", 0.0), ("neo-hookean+yeoh", 3e3)]:
        F = np.eye(3)[None] + 0.25 * rng.standard_normal((5, 3, 3))
        F[np.linalg.det(F) < 0.3] = np.eye(3)  # keep valid ones
        mat = tf.Material(np.full(5, 1e4), np.full(5, 4e4), np.full(5, c2))
        P, A = tf.stress_tangent(F, mat)
        h = 1e-6
        Pfd = np.zeros_like(P)
        Afd = np.zeros_like(A)
        for k in range(3):
            for L in range(3):
                dF = np.zeros((3, 3))
                dF[k, L] = h
                Pfd[:, k, L] = (tf.energy_density(F + dF, mat) - tf.energy_density(F - dF, mat)) / (2 * h)
                Pp, _ = tf.stress_tangent(F + dF, mat, tangent=False)
                Pm, _ = tf.stress_tangent(F - dF, mat, tangent=False)
                Afd[:, :, :, k, L] = (Pp - Pm) / (2 * h)
        out[label] = {
            "P_vs_fd_of_W": float(np.abs(P - Pfd).max() / np.abs(P).max()),
            "A_vs_fd_of_P": float(np.abs(A - Afd).max() / np.abs(A).max()),
            "A_major_symmetry": float(np.abs(A - np.transpose(A, (0, 3, 4, 1, 2))).max() / np.abs(A).max()),
        }
    return out


def small_block(nx=3, ny=2, nz=2, L=0.02, W=0.012, H=0.01):
    """A structured tet mesh of a box (6 tets per hexahedron), independent of Gmsh."""
    xs, ys, zs = np.linspace(0, L, nx + 1), np.linspace(0, W, ny + 1), np.linspace(0, H, nz + 1)
    X = np.array([[x, y, z] for z in zs for y in ys for x in xs])
    idx = lambda i, j, k: (k * (ny + 1) + j) * (nx + 1) + i
    T = []
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                c = [idx(i, j, k), idx(i + 1, j, k), idx(i + 1, j + 1, k), idx(i, j + 1, k),
                     idx(i, j, k + 1), idx(i + 1, j, k + 1), idx(i + 1, j + 1, k + 1), idx(i, j + 1, k + 1)]
                for a, b, cc, d in [(0, 1, 2, 6), (0, 2, 3, 6), (0, 3, 7, 6), (0, 7, 4, 6), (0, 4, 5, 6), (0, 5, 1, 6)]:
                    T.append([c[a], c[b], c[cc], c[d]])
    return X, np.array(T)


def check_assembly(rng):
    X, T = small_block()
    ne = len(T)
    mat = tf.Material(rng.uniform(5e3, 2e4, ne), rng.uniform(1e4, 8e4, ne), rng.uniform(0, 5e3, ne))
    body = tf.Body(X, T, mat)
    u = 4e-4 * rng.standard_normal(3 * body.n)  # ~4 % strain on 3 mm elements
    f, K = body.internal(u)
    res = {"energy_gradient": [], "tangent": []}
    for _ in range(3):
        v = rng.standard_normal(3 * body.n)
        h = 1e-7
        dE = (body.strain_energy(u + h * v) - body.strain_energy(u - h * v)) / (2 * h)
        res["energy_gradient"].append(abs(dE - f @ v) / abs(f @ v))
        fp, _ = body.internal(u + h * v, tangent=False)
        fm, _ = body.internal(u - h * v, tangent=False)
        Kv = K @ v
        res["tangent"].append(float(np.linalg.norm((fp - fm) / (2 * h) - Kv) / np.linalg.norm(Kv)))
    res["tangent_symmetry"] = float(abs(K - K.T).max() / abs(K).max())
    return {k: (max(v) if isinstance(v, list) else v) for k, v in res.items()}


def linear_stiffness(X, T, E, nu):
    """Classic small-strain stiffness K = sum V B^T D B (Voigt), written separately from truthfem."""
    import scipy.sparse as sp
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    mu = E / (2 * (1 + nu))
    D = np.zeros((6, 6))
    D[:3, :3] = lam
    D[np.arange(3), np.arange(3)] += 2 * mu
    D[3:, 3:] = mu * np.eye(3)
    rows, cols, vals = [], [], []
    for tet in T:
        M = np.ones((4, 4))
        M[:, 1:] = X[tet]
        C = np.linalg.inv(M)  # N_a = C[0,a] + C[1:,a].x
        V = abs(np.linalg.det(M)) / 6
        g = C[1:, :].T  # (4,3)
        Bm = np.zeros((6, 12))
        for a in range(4):
            gx, gy, gz = g[a]
            Bm[:, 3 * a:3 * a + 3] = [[gx, 0, 0], [0, gy, 0], [0, 0, gz], [0, gz, gy], [gz, 0, gx], [gy, gx, 0]]
        Ke = V * Bm.T @ D @ Bm
        dof = (3 * tet[:, None] + np.arange(3)).ravel()
        rows.append(np.repeat(dof, 12))
        cols.append(np.tile(dof, 12))
        vals.append(Ke.ravel())
    n = 3 * len(X)
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))


def check_linear_tangent(rng):
    X, T = small_block(4, 3, 2)
    E, nu = 3e4, 0.43
    body = tf.Body(X, T, tf.Material.from_E_nu(E, nu, len(T)))
    _, K0 = body.internal(np.zeros(3 * body.n))
    Kl = linear_stiffness(X, body.T, E, nu)
    return {"K0_vs_linear_BtDB": float(abs(K0 - Kl).max() / abs(Kl).max())}


def uniaxial_analytic(E, nu, c2, P11):
    """Homogeneous uniaxial stress: stretches (l1, l2) with dW/dl1 = P11, dW/dl2 = 0 (per transverse
    direction), W written out from the invariants of F = diag(l1, l2, l2)."""
    mu = E / (2 * (1 + nu))
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))

    def W(l1, l2):
        I1 = l1**2 + 2 * l2**2
        J = l1 * l2**2
        Ib = J ** (-2 / 3) * I1
        return mu / 2 * (I1 - 3) - mu * np.log(J) + lam / 2 * np.log(J) ** 2 + c2 * (Ib - 3) ** 2

    def eqs(v):
        l1, l2 = v
        h = 1e-7
        d1 = (W(l1 + h, l2) - W(l1 - h, l2)) / (2 * h)
        d2 = (W(l1, l2 + h) - W(l1, l2 - h)) / (2 * h) / 2  # two transverse directions
        return [d1 - P11, d2]

    l1, l2 = so.fsolve(eqs, [1 + P11 / E, 1 - nu * P11 / E], xtol=1e-13)
    return l1, l2


def check_bar():
    Lb, Wb, Hb = 0.1, 0.02, 0.02
    X, T = small_block(10, 2, 2, Lb, Wb, Hb)
    E, nu = 2e4, 0.45
    out = {}
    for c2 in [0.0, 2e3]:
        mat = tf.Material.from_E_nu(E, nu, len(T))
        mat.c2[:] = c2
        body = tf.Body(X, T, mat)
        fixed = np.zeros(3 * body.n, bool)
        fixed[0::3] |= X[:, 0] < 1e-12
        fixed[1::3] |= X[:, 1] < 1e-12
        fixed[2::3] |= X[:, 2] < 1e-12
        prob = tf.Problem(body, fixed_dofs=fixed)
        end = np.flatnonzero(X[:, 0] > Lb - 1e-12)
        # uniform dead traction on the end face: consistent nodal forces of its triangles
        faces = tf.boundary_faces(body.T)
        endf = faces[np.all(X[faces][:, :, 0] > Lb - 1e-12, axis=1)]
        areas = 0.5 * np.linalg.norm(np.cross(X[endf[:, 1]] - X[endf[:, 0]], X[endf[:, 2]] - X[endf[:, 0]]), axis=1)
        w = np.zeros(body.n)
        np.add.at(w, endf.ravel(), np.repeat(areas / 3, 3))
        assert abs(w.sum() - Wb * Hb) < 1e-12 and set(np.flatnonzero(w)) <= set(end)
        cases = {"small_tension": 1e-4 * E, "tension_20pct": None, "compression_15pct": None}
        # dead nominal stress giving the target stretch (from the analytic solution's inverse)
        for name, target in [("tension_20pct", 1.2), ("compression_15pct", 0.85)]:
            cases[name] = so.brentq(lambda s: uniaxial_analytic(E, nu, c2, s)[0] - target, -0.9 * E, 0.9 * E)
        res = {}
        for name, s11 in cases.items():
            f = np.zeros(3 * body.n)
            f[0::3] = s11 * w
            u, it = prob.solve(f, steps=4)
            U = u.reshape(-1, 3)
            if name == "small_tension":
                lin = np.stack([s11 * X[:, 0] / E, -nu * s11 * X[:, 1] / E, -nu * s11 * X[:, 2] / E], axis=1)
                res[name] = {"max_rel_err_vs_linear": float(np.abs(U - lin).max() / np.abs(lin).max()),
                             "strain": s11 / E, "newton_iterations": it}
            else:
                l1, l2 = uniaxial_analytic(E, nu, c2, s11)
                ex = np.stack([(l1 - 1) * X[:, 0], (l2 - 1) * X[:, 1], (l2 - 1) * X[:, 2]], axis=1)
                res[name] = {"stretch": [float(l1), float(l2)], "nominal_stress_Pa": float(s11),
                             "max_rel_err_vs_analytic": float(np.abs(U - ex).max() / np.abs(ex).max()),
                             "newton_iterations": it}
        out["neo-hookean" if c2 == 0 else f"neo-hookean+yeoh(c2={c2:g} Pa)"] = res
    return out


def check_probe_small_load():
    blk = shapes.Block(0.06, 0.06, 0.03)
    md = shapes.mesh_shape(blk, "truth", h_fine=0.003, h_coarse=0.008, grade_dist=0.02, seed=5)
    E, nu = 2e4, 0.4
    body = tf.Body(md.X, md.T, tf.Material.from_E_nu(E, nu, len(md.T)))
    prob = tf.Problem(body, np.unique(md.faces["bottom"]))
    # a 1 N downward force on the top nodes within 8 mm of the centre, area-weighted
    top = md.faces["top"]
    A = 0.5 * np.linalg.norm(np.cross(md.X[top[:, 1]] - md.X[top[:, 0]], md.X[top[:, 2]] - md.X[top[:, 0]]), axis=1)
    w = np.zeros(body.n)
    np.add.at(w, top.ravel(), np.repeat(A / 3, 3))
    w[np.linalg.norm(md.X[:, :2] - 0.03, axis=1) > 0.008] = 0
    f = np.zeros(3 * body.n)
    f[2::3] = -w / w.sum()
    _, K0 = body.internal(np.zeros(3 * body.n))
    free = prob.free
    ulin = np.zeros(3 * body.n)
    ulin[free] = tf.factor(K0[free][:, free])(f[free])
    rows = []
    for t in [1.0, 0.3, 0.1, 0.03, 0.01]:
        u, it = prob.solve(t * f, steps=1)
        d = np.linalg.norm(u - t * ulin) / np.linalg.norm(t * ulin)
        rows.append({"force_N": t, "max_disp_mm": float(1e3 * np.abs(u).max()), "rel_diff_vs_linear": float(d), "newton_iterations": it})
    return {"tets": len(md.T), "E": E, "nu": nu, "rows": rows}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("-o", default=None)
    a = ap.parse_args()
    rng = np.random.default_rng(7)
    r = {"material_point": check_material(rng), "assembly": check_assembly(rng),
         "linear_tangent": check_linear_tangent(rng), "bar": check_bar(), "probe_small_load": check_probe_small_load()}
    print(json.dumps(r, indent=1))
    ok = True
    for v in r["material_point"].values():
        ok &= v["P_vs_fd_of_W"] < 1e-6 and v["A_vs_fd_of_P"] < 1e-6 and v["A_major_symmetry"] < 1e-12
    ok &= r["assembly"]["energy_gradient"] < 1e-6 and r["assembly"]["tangent"] < 1e-6
    ok &= r["linear_tangent"]["K0_vs_linear_BtDB"] < 1e-12
    for v in r["bar"].values():
        ok &= v["small_tension"]["max_rel_err_vs_linear"] < 1e-3
        ok &= v["tension_20pct"]["max_rel_err_vs_analytic"] < 1e-6 and v["compression_15pct"]["max_rel_err_vs_analytic"] < 1e-6
    rows = r["probe_small_load"]["rows"]
    ok &= rows[-1]["rel_diff_vs_linear"] < 0.02 * rows[0]["rel_diff_vs_linear"] * 5  # ~ proportional to t
    r["passed"] = bool(ok)
    if a.o:
        with open(a.o, "w") as fh:
            json.dump(r, fh, indent=1)
    print("PASSED" if ok else "FAILED")
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
