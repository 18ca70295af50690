"""Independent static contact-data generator for palpate (see README.md beside this file).

    python independent_static.py -o OUT --seed 3 --shape dome --effect inclusion [--quick]
    python independent_static.py -o OUT --seed 3            # shape and effect drawn too

Writes a palpate static dataset (docs/dataset.md: dataset.toml, mesh.msh, markers.csv,
contacts.csv, measurements.csv) and truth.json (never read by palpate).

Truth: compressible Neo-Hookean W = mu/2 (I1 - 3) - mu ln J + lam/2 (ln J)^2 (+ Yeoh c2 (Ib1 - 3)^2
for the stiffening effect), P1 tets on a fine graded Gmsh mesh, Newton + sparse direct solve
(truthfem.py). Probe load: a Hertz-like pressure p ~ sqrt(1 - (s/a)^2) over the truth mesh's surface
triangles facing the probe (s = distance from the probe axis, a = probe radius), integrated with a
3-point rule, carrying the whole true force vector (dead load).

Every range a draw is taken from is in RANGES below.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import time

import numpy as np

import shapes
import truthfem as tf

EFFECTS = [
    "none", "inclusion", "layer", "stiffening", "sensor-nonlinearity", "compliant-support",
    "registration-each", "friction", "tilt-each", "gravity", "stand-off", "force-scale", "noise",
]
SHAPES = ["block", "dome", "cylinder"]

RANGES = {
    # base draw
    "E_Pa": (5e3, 2e5),                 # log-uniform
    "nu": (0.2, 0.49),                  # uniform
    "probe_radius_m": (0.006, 0.012),   # uniform
    "contacts": (4, 8),                 # integer, inclusive
    "indent_target_m": (1.0e-3, 4.0e-3),  # log-uniform; |f| = delta 2 a E / (1 - nu^2) (flat punch on a half-space)
    "reported_off_normal_deg": (0.0, 12.0),  # declared direction of the reported force, off the inward normal
    "markers": (40, 250),               # integer, inclusive
    "marker_min_height_m": 0.003,       # markers above the table
    "marker_noise_m": (0.03e-3, 0.2e-3),  # declared sigma, uniform
    "rest_noise_factor": 1 / math.sqrt(10),  # the rest scan: mean of 10 frames
    "occlusion_prob": (0.0, 0.08),      # random drop per (measurement, marker)
    "probe_shadow": 1.2,                # markers within 1.2 a of the contact are hidden by the probe
    "dataset_tets": (1500, 3000),
    # effects
    "inclusion_radius_frac": (0.15, 0.4),   # of the smallest dimension
    "inclusion_stiff": (3.0, 20.0),         # E ratio, log-uniform
    "inclusion_soft": (0.1, 0.3),           # E ratio, log-uniform
    "layer_thickness_frac": (0.15, 0.4),    # of the height
    "layer_soft": (0.2, 0.5),               # E ratio, log-uniform
    "layer_stiff": (2.0, 5.0),              # E ratio, log-uniform
    "yeoh_c2_over_mu": (0.3, 10.0),         # log-uniform
    "sensor_power_b": [(0.6, 0.85), (1.15, 1.5)],  # reported = a f^b, a = f_ref^(1-b)
    "support_equiv_thickness_m": (0.002, 0.03),  # Winkler springs k_n = E / l per area, log-uniform
    "support_tangential_ratio": (0.2, 1.0),
    "registration_translation_m": (0.05e-3, 0.5e-3),  # RMS per measurement, log-uniform
    "registration_rotation_deg": (0.05, 0.5),         # RMS per measurement, log-uniform
    "friction_fraction": (0.1, 0.4),        # |f_t| = frac U(0.5, 1) |f|, random tangential direction
    "tilt_max_deg": (5.0, 15.0),            # per measurement U(0.5, 1) x max, random azimuth
    "gravity_density": (900.0, 1250.0),     # kg/m^3, g = 9.81 along -z, declared nowhere
    "standoff_m": (0.001, 0.003),           # post length, +-10 % per marker
    "force_scale_log_sd": (0.05, 0.25),     # log gain, random walk normalised to this RMS
    "noise_factor": (1.5, 3.0),             # actual sigma / declared sigma
}


def loguniform(rng, lo, hi):
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def rotate(v, axis, angle):
    axis = axis / np.linalg.norm(axis)
    return v * math.cos(angle) + np.cross(axis, v) * math.sin(angle) + axis * (axis @ v) * (1 - math.cos(angle))


def random_perp(rng, d):
    a = rng.standard_normal(3)
    a -= (a @ d) * d
    return a / np.linalg.norm(a)


def rotvec_matrix(w):
    th = np.linalg.norm(w)
    if th < 1e-15:
        return np.eye(3)
    k = w / th
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * Kx + (1 - math.cos(th)) * Kx @ Kx


def tri_area_normal(X, F):
    c = np.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]])
    a = np.linalg.norm(c, axis=1)
    return 0.5 * a, c / a[:, None]


# ----------------------------------------------------------------------------------------------
# the truth model

class Truth:
    def __init__(self, shape, md: shapes.MeshData):
        self.shape, self.md = shape, md
        self.X, self.T = md.X, md.T
        self.bottom_nodes = np.unique(md.faces["bottom"])
        # outward-oriented boundary faces with their group
        bf = tf.boundary_faces(tf.tet_geometry(md.X, md.T)[0])
        key = {tuple(sorted(f)): g for g, fs in md.faces.items() for f in fs}
        self.faces = bf
        self.face_group = np.array([key.get(tuple(sorted(f)), "?") for f in bf])
        assert (self.face_group != "?").all(), "surface triangle without a group"
        self.area, self.normal = tri_area_normal(md.X, bf)
        self.centroids = np.einsum("eai->ei", md.X[md.T]) / 4

    def element_fraction(self, inside):
        """Fraction of each element inside a region given by a vectorised predicate on points."""
        P = self.X[self.T]  # (ne,4,3)
        c = P.mean(axis=1)
        pts = [c] + [0.6 * P[:, a] + 0.4 * c for a in range(4)]
        pts += [0.5 * (P[:, a] + P[:, b]) * 0.8 + 0.2 * c for a, b in [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]]
        return np.mean([inside(p) for p in pts], axis=0)

    def probe_load(self, c, fvec, axis, a):
        """Nodal forces of a Hertz-like pressure sqrt(1 - (s/a)^2) around the probe axis through c,
        on the non-bottom surface triangles facing the probe; the resultant equals fvec."""
        axis = axis / np.linalg.norm(axis)
        ok = (self.face_group != "bottom") & (self.normal @ axis < -0.2)
        F = self.faces[ok]
        A = self.area[ok]
        bary = np.array([[2 / 3, 1 / 6, 1 / 6], [1 / 6, 2 / 3, 1 / 6], [1 / 6, 1 / 6, 2 / 3]])
        w = np.zeros(len(self.X))
        for b in bary:
            q = np.einsum("k,fki->fi", b, self.X[F])
            r = q - c
            ax = r @ axis
            s = np.linalg.norm(r - ax[:, None] * axis, axis=1)
            p = np.sqrt(np.clip(1 - (s / a) ** 2, 0, None)) * (np.abs(ax) < a)
            np.add.at(w, F.ravel(), (np.outer(p * A / 3, b)).ravel())
        w[self.bottom_nodes] = 0
        if w.sum() <= 0:
            raise RuntimeError("probe covers no truth surface")
        f = np.zeros(3 * len(self.X))
        f.reshape(-1, 3)[:] = np.outer(w / w.sum(), fvec)
        return f

    def body_force(self, rho, g):
        V = tf.tet_geometry(self.X, self.T)[1]
        w = np.zeros(len(self.X))
        np.add.at(w, self.T.ravel(), np.repeat(V / 4, 4))
        f = np.zeros(3 * len(self.X))
        f.reshape(-1, 3)[:] = np.outer(w * rho, g)
        return f

    def bottom_springs(self, kn, kt):
        Fb = self.faces[self.face_group == "bottom"]
        A = self.area[self.face_group == "bottom"]
        w = np.zeros(len(self.X))
        np.add.at(w, Fb.ravel(), np.repeat(A / 3, 3))
        k = np.zeros(3 * len(self.X))
        k[0::3], k[1::3], k[2::3] = kt * w, kt * w, kn * w
        return k

    def simulate(self, E_el, nu, loads, c2=None, rho=0.0, springs=None, log=None):
        """loads: list of nodal force vectors (probe only). Returns (U_rest (n,3), [U_i (n,3)], info)."""
        ne = len(self.T)
        mat = tf.Material.from_E_nu(E_el, nu, ne)
        if c2 is not None:
            mat.c2[:] = c2
        body = tf.Body(self.X, self.T, mat)
        prob = tf.Problem(body, fixed_nodes=() if springs is not None else self.bottom_nodes, spring=springs)
        n3 = 3 * len(self.X)
        fg = self.body_force(rho, np.array([0, 0, -9.81])) if rho else np.zeros(n3)
        info = {"newton_iterations": [], "seconds": 0.0}
        t0 = time.time()
        u_rest = np.zeros(n3)
        if rho:
            u_rest, it = prob.solve(fg, steps=2)
            info["newton_iterations"].append(it)
        _, K = prob.residual(u_rest, fg)
        solve0 = tf.factor(K[prob.free][:, prob.free])
        out = []
        for f in loads:
            u0 = u_rest.copy()
            u0[prob.free] += solve0(f[prob.free])  # linear predictor
            try:
                if not np.isfinite(prob.potential(u0, fg + f)):
                    raise tf.SolveError("predictor inverts an element")
                u, it = prob.newton(u0, fg + f)
            except tf.SolveError:
                u, it = prob.solve(fg + f, u_start=u_rest, f_start=fg, steps=3)
            info["newton_iterations"].append(it)
            out.append(u.reshape(-1, 3))
        info["seconds"] = time.time() - t0
        if log:
            log(f"    truth solve: {len(loads)} loads, Newton iterations {info['newton_iterations']}, {info['seconds']:.1f} s")
        return u_rest.reshape(-1, 3), out, info


# ----------------------------------------------------------------------------------------------
# markers on the truth surface

class Markers:
    def __init__(self, truth: Truth, rng, n):
        vis = (truth.face_group != "bottom")
        cz = truth.X[truth.faces].mean(axis=1)[:, 2]
        vis &= cz > RANGES["marker_min_height_m"]
        idx = np.flatnonzero(vis)
        p = truth.area[idx] / truth.area[idx].sum()
        self.face = truth.faces[rng.choice(idx, size=n, p=p)]
        r1, r2 = rng.uniform(size=n), rng.uniform(size=n)
        s = np.sqrt(r1)
        self.bary = np.stack([1 - s, s * (1 - r2), s * r2], axis=1)
        self.truth = truth

    def positions(self, U, standoff=None):
        x = self.truth.X + U
        p = np.einsum("mk,mki->mi", self.bary, x[self.face])
        if standoff is not None:
            c = np.cross(x[self.face[:, 1]] - x[self.face[:, 0]], x[self.face[:, 2]] - x[self.face[:, 0]])
            p = p + standoff[:, None] * c / np.linalg.norm(c, axis=1)[:, None]
        return p


# ----------------------------------------------------------------------------------------------

def draw_effect(rng, effect, truth: Truth, shape, E, M):
    """Effect parameters (dict) drawn within RANGES."""
    R = RANGES
    p = {"effect": effect}
    ext = np.array(shape.extent())
    dims = ext[3:] - ext[:3]
    if effect == "inclusion":
        stiff = rng.uniform() < 0.5
        p["contrast"] = loguniform(rng, *(R["inclusion_stiff"] if stiff else R["inclusion_soft"]))
        r = rng.uniform(*R["inclusion_radius_frac"]) * dims.min()
        for _ in range(2000):
            c = ext[:3] + rng.uniform(size=3) * dims
            if shape.dist_inside(c[None])[0] >= r + 0.002:
                break
            if _ % 200 == 199:
                r *= 0.85
        else:
            raise RuntimeError("no room for the inclusion")
        p["centre_m"], p["radius_m"] = c.tolist(), float(r)
        p["magnitude"] = float(abs(math.log(p["contrast"])))
    elif effect == "layer":
        stiff = rng.uniform() < 0.5
        p["contrast"] = loguniform(rng, *(R["layer_stiff"] if stiff else R["layer_soft"]))
        p["thickness_m"] = float(rng.uniform(*R["layer_thickness_frac"]) * dims[2])
        p["magnitude"] = float(abs(math.log(p["contrast"])))
    elif effect == "stiffening":
        p["c2_over_mu"] = loguniform(rng, *R["yeoh_c2_over_mu"])
        p["magnitude"] = p["c2_over_mu"]
    elif effect == "sensor-nonlinearity":
        lo, hi = R["sensor_power_b"][int(rng.uniform() < 0.5)]
        p["b"] = float(rng.uniform(lo, hi))
        p["ref_factor"] = float(math.exp(rng.uniform(-0.5, 0.5)))
        p["magnitude"] = abs(p["b"] - 1)
    elif effect == "compliant-support":
        p["equiv_thickness_m"] = loguniform(rng, *R["support_equiv_thickness_m"])
        p["k_normal_Pa_per_m"] = E / p["equiv_thickness_m"]
        p["tangential_ratio"] = float(rng.uniform(*R["support_tangential_ratio"]))
        p["magnitude"] = 1e-3 / p["equiv_thickness_m"]
    elif effect == "registration-each":
        st = loguniform(rng, *R["registration_translation_m"])
        sr = math.radians(loguniform(rng, *R["registration_rotation_deg"]))
        p["translation_rms_m"], p["rotation_rms_deg"] = st, math.degrees(sr)
        p["translations_m"] = (rng.standard_normal((M, 3)) * st / math.sqrt(3)).tolist()
        p["rotvecs_rad"] = (rng.standard_normal((M, 3)) * sr / math.sqrt(3)).tolist()
        p["pivot_m"] = (0.5 * (ext[:3] + ext[3:])).tolist()
        p["magnitude"] = st
    elif effect == "friction":
        p["fraction"] = float(rng.uniform(*R["friction_fraction"]))
        p["per_measurement_fraction"] = (p["fraction"] * rng.uniform(0.5, 1.0, M)).tolist()
        p["magnitude"] = p["fraction"]
    elif effect == "tilt-each":
        p["max_deg"] = float(rng.uniform(*R["tilt_max_deg"]))
        p["per_measurement_deg"] = (p["max_deg"] * rng.uniform(0.5, 1.0, M)).tolist()
        p["magnitude"] = p["max_deg"]
    elif effect == "gravity":
        p["density"] = float(rng.uniform(*R["gravity_density"]))
        p["magnitude"] = p["density"]
    elif effect == "stand-off":
        p["post_m"] = float(rng.uniform(*R["standoff_m"]))
        p["magnitude"] = p["post_m"]
    elif effect == "force-scale":
        sd = float(rng.uniform(*R["force_scale_log_sd"]))
        w = np.cumsum(rng.standard_normal(M))
        w -= w.mean()
        w = w / max(np.sqrt(np.mean(w**2)), 1e-12) * sd
        p["log_sd"], p["gains"] = sd, np.exp(w).tolist()
        p["magnitude"] = sd
    elif effect == "noise":
        p["factor"] = float(rng.uniform(*R["noise_factor"]))
        p["magnitude"] = p["factor"]
    elif effect == "none":
        p["magnitude"] = 0.0
    else:
        raise ValueError(f"unknown effect {effect!r}")
    return p


def generate(out, seed, shape_kind=None, effect=None, quick=False, verbose=True):
    t_start = time.time()
    log = print if verbose else (lambda *a, **k: None)
    R = RANGES
    rng = np.random.default_rng([seed, 11])      # the base draw (shape, material, probes, markers)
    rng_e = np.random.default_rng([seed, 22])    # the effect
    rng_n = np.random.default_rng([seed, 33])    # noise and occlusion
    if shape_kind is None:
        shape_kind = SHAPES[int(rng.integers(len(SHAPES)))]
    if effect is None:
        effect = EFFECTS[int(rng_e.integers(len(EFFECTS)))]
    shape = shapes.draw_shape(rng, shape_kind)
    E = loguniform(rng, *R["E_Pa"])
    nu = float(rng.uniform(*R["nu"]))
    a = float(rng.uniform(*R["probe_radius_m"]))
    M = int(rng.integers(R["contacts"][0], R["contacts"][1] + 1))
    if quick:
        M = min(M, 4)
    contacts = []
    for i in range(M):
        c, n = shape.sample_probe(rng, a + 0.004)
        ang = math.radians(rng.uniform(*R["reported_off_normal_deg"]))
        d = rotate(-n, random_perp(rng, n), ang)
        delta = loguniform(rng, *R["indent_target_m"])
        mag = delta * 2 * a * E / (1 - nu**2)
        contacts.append({"id": f"p{i + 1}", "point": c, "normal": n, "reported": mag * d})
    n_markers = int(rng.integers(R["markers"][0], R["markers"][1] + 1))
    sigma = float(rng.uniform(*R["marker_noise_m"]))
    p_occ = float(rng.uniform(*R["occlusion_prob"]))
    os.makedirs(out, exist_ok=True)
    log(f"draw seed={seed} shape={shape_kind} effect={effect}: E={E:.4g} Pa nu={nu:.3f} a={a * 1e3:.1f} mm M={M} markers={n_markers} sigma={sigma * 1e6:.0f} um")

    # meshes: the truth (fine, graded) and the dataset (coarse, independent)
    h_fine = 0.0048 if quick else min(0.003, a / 2.2)
    t0 = time.time()
    tmd = shapes.mesh_shape(shape, "truth", h_fine=h_fine, h_coarse=3 * h_fine, grade_dist=0.02,
                            seed=int(rng.integers(1, 10_000)))
    truth = Truth(shape, tmd)
    n_target = int(rng.uniform(*R["dataset_tets"]))
    dmd, h_ds = shapes.dataset_mesh(shape, rng, os.path.join(out, "mesh.msh"), n_target=n_target)
    # like a user: refine the dataset mesh until every contact reaches a free surface node of it
    remesh = 0
    while True:
        bnodes = np.unique(tf.boundary_faces(tf.tet_geometry(dmd.X, dmd.T)[0]))
        free = np.setdiff1d(bnodes, np.unique(dmd.faces["bottom"]))
        dmin = max(np.linalg.norm(dmd.X[free] - c["point"], axis=1).min() for c in contacts)
        if dmin <= a or remesh >= 3:
            break
        remesh += 1
        n_target = int(n_target * 1.5)
        dmd, h_ds = shapes.dataset_mesh(shape, rng, os.path.join(out, "mesh.msh"), n_target=n_target)
    log(f"  meshes: truth {len(tmd.T)} tets (h {h_fine * 1e3:.1f}-{3 * h_fine * 1e3:.1f} mm), dataset {len(dmd.T)} tets (h {h_ds * 1e3:.1f} mm, remeshed {remesh}x), {time.time() - t0:.1f} s")

    markers = Markers(truth, rng, n_markers)
    ep = draw_effect(rng_e, effect, truth, shape, E, M)

    # material per element and the two worlds (with / without the effect)
    E_el = np.full(len(tmd.T), E)
    E_twin = E_el.copy()
    c2 = None
    rho = 0.0
    springs = None
    if effect == "inclusion":
        cc, r = np.array(ep["centre_m"]), ep["radius_m"]
        phi = truth.element_fraction(lambda q: np.linalg.norm(q - cc, axis=1) <= r)
        E_el = E * np.exp(phi * math.log(ep["contrast"]))
    elif effect == "layer":
        t = ep["thickness_m"]
        phi = truth.element_fraction(lambda q: shape.top_z(q[:, 0], q[:, 1]) - q[:, 2] <= t)
        E_el = E * np.exp(phi * math.log(ep["contrast"]))
    elif effect == "stiffening":
        c2 = ep["c2_over_mu"] * E / (2 * (1 + nu))
    elif effect == "gravity":
        rho = ep["density"]
    elif effect == "compliant-support":
        springs = truth.bottom_springs(ep["k_normal_Pa_per_m"], ep["tangential_ratio"] * ep["k_normal_Pa_per_m"])

    reported = [c["reported"] for c in contacts]
    true_f, axes = [], []
    for i, c in enumerate(contacts):
        f = c["reported"].copy()
        d = f / np.linalg.norm(f)
        axis = d
        if effect == "sensor-nonlinearity":
            pass  # handled below (the reported force is derived from the true one)
        elif effect == "friction":
            tdir = random_perp(rng_e, d)
            f = f + ep["per_measurement_fraction"][i] * np.linalg.norm(f) * tdir
        elif effect == "tilt-each":
            f = rotate(f, random_perp(rng_e, d), math.radians(ep["per_measurement_deg"][i]))
            axis = f / np.linalg.norm(f)
        elif effect == "force-scale":
            f = f * ep["gains"][i]
        true_f.append(f)
        axes.append(axis)
    if effect == "sensor-nonlinearity":
        # the true forces are the drawn ones; the sensor reports a f^b with a = f_ref^(1 - b)
        mags = np.array([np.linalg.norm(f) for f in true_f])
        fref = float(np.exp(np.mean(np.log(mags)))) * ep["ref_factor"]
        ep["f_ref_N"] = fref
        ep["a"] = fref ** (1 - ep["b"])
        reported = [f / np.linalg.norm(f) * ep["a"] * np.linalg.norm(f) ** ep["b"] for f in true_f]
    ep["true_forces_N"] = [f.tolist() for f in true_f]
    ep["reported_forces_N"] = [f.tolist() for f in reported]

    loads = [truth.probe_load(c["point"], f, ax, a) for c, f, ax in zip(contacts, true_f, axes)]
    log(f"  effect {json.dumps({k: v for k, v in ep.items() if not isinstance(v, list)})}")
    Ur, Us, info = truth.simulate(E_el, nu, loads, c2=c2, rho=rho, springs=springs, log=log)
    force_side = effect in ("sensor-nonlinearity", "friction", "tilt-each", "force-scale")
    material_side = effect in ("inclusion", "layer", "stiffening", "gravity", "compliant-support")
    if force_side or material_side:
        loads_twin = [truth.probe_load(c["point"], f, f / np.linalg.norm(f), a) for c, f in zip(contacts, reported)]
        Ur_t, Us_t, info_t = truth.simulate(E_twin, nu, loads_twin, log=log)
    else:
        Ur_t, Us_t, info_t = Ur, Us, None

    standoff = None
    if effect == "stand-off":
        standoff = ep["post_m"] * rng_e.uniform(0.9, 1.1, n_markers)
    rest_clean = markers.positions(Ur, standoff)
    rest_twin = markers.positions(Ur_t)
    meas_clean = np.stack([markers.positions(U, standoff) for U in Us])
    meas_twin = np.stack([markers.positions(U) for U in Us_t])
    if effect == "registration-each":
        piv = np.array(ep["pivot_m"])
        for i in range(M):
            Rm = rotvec_matrix(np.array(ep["rotvecs_rad"][i]))
            meas_clean[i] = piv + (meas_clean[i] - piv) @ Rm.T + np.array(ep["translations_m"][i])

    # occlusion: hidden under the probe, and at random
    obs = np.ones((M, n_markers), bool)
    for i, c in enumerate(contacts):
        near = np.linalg.norm(rest_twin - c["point"], axis=1) < R["probe_shadow"] * a
        obs[i] &= ~near
    obs &= rng_n.uniform(size=obs.shape) >= p_occ
    for i in range(M):  # every measurement keeps at least 5 markers
        if obs[i].sum() < 5:
            obs[i, np.argsort(-np.linalg.norm(rest_twin - contacts[i]["point"], axis=1))[:5]] = True
    z = rng_n.standard_normal(meas_clean.shape)
    sigma_actual = sigma * (ep["factor"] if effect == "noise" else 1.0)
    meas = meas_clean + sigma_actual * z
    rest = rest_clean + sigma * R["rest_noise_factor"] * rng_n.standard_normal(rest_clean.shape)

    # effect SNR: the effect's change of the observed marker data over the declared sigma
    d_eff = meas_clean - rest_clean[None]
    d_twin = meas_twin - rest_twin[None]
    if effect == "noise":
        diff_disp = (sigma_actual - sigma) * z
        diff_pos = diff_disp
    else:
        diff_disp = d_eff - d_twin
        diff_pos = meas_clean - meas_twin
    snr = float(np.linalg.norm(diff_disp[obs]) / sigma)
    snr_pos = float(np.linalg.norm(diff_pos[obs]) / sigma)
    n_obs = int(obs.sum())
    rms_disp = float(np.sqrt(np.mean(np.sum(d_twin[obs] ** 2, axis=1))))

    # write the dataset
    mk = [f"m{k + 1}" for k in range(n_markers)]
    with open(os.path.join(out, "markers.csv"), "w") as fh:
        fh.write("marker,x,y,z\n")
        for k in range(n_markers):
            fh.write(f"{mk[k]},{rest[k, 0]:.9e},{rest[k, 1]:.9e},{rest[k, 2]:.9e}\n")
    with open(os.path.join(out, "contacts.csv"), "w") as fh:
        fh.write("measurement,x,y,z,fx,fy,fz,radius\n")
        for c, f in zip(contacts, reported):
            p = c["point"]
            fh.write(f"{c['id']},{p[0]:.9e},{p[1]:.9e},{p[2]:.9e},{f[0]:.9e},{f[1]:.9e},{f[2]:.9e},{a:.9e}\n")
    with open(os.path.join(out, "measurements.csv"), "w") as fh:
        fh.write("measurement,marker,x,y,z\n")
        for i, c in enumerate(contacts):
            for k in np.flatnonzero(obs[i]):
                x = meas[i, k]
                fh.write(f"{c['id']},{mk[k]},{x[0]:.9e},{x[1]:.9e},{x[2]:.9e}\n")
    with open(os.path.join(out, "dataset.toml"), "w") as fh:
        fh.write(f'name = "indep-{shape_kind}-{effect}-s{seed}"\n')
        fh.write(f'description = "independent generator (tests/generators/independent_static.py), seed {seed}"\n')
        fh.write('units = "SI"\nmesh = "mesh.msh"\nfixed_group = "bottom"\n')
        fh.write(f"probe_radius = {a:.9e}\nmarker_noise = {sigma:.9e}\n")
    truth_json = {
        "generator": "tests/generators/independent_static.py",
        "seed": seed, "quick": quick, "shape": shape_kind, "shape_params": shape.params(),
        "effect": effect, "effect_params": ep, "magnitude": ep["magnitude"],
        "snr": snr_pos, "snr_definition": "||(observed marker positions with the effect) - (same draw without it)||_2 / declared sigma, over all observed (measurement, marker) entries, noise-free",
        "snr_displacement": snr, "snr_displacement_definition": "the same on displacements, each world's measured positions minus its own rest scan (a shift common to the rest scan and the measurements, e.g. a gravity sag, does not count)",
        "E_Pa": E, "nu": nu, "probe_radius_m": a, "marker_noise_declared_m": sigma,
        "marker_noise_actual_m": sigma_actual, "rest_noise_m": sigma * R["rest_noise_factor"],
        "occlusion_prob": p_occ, "observed_entries": n_obs, "markers": n_markers, "measurements": M,
        "rms_marker_displacement_m": rms_disp,
        "max_marker_displacement_m": float(np.linalg.norm(d_twin[obs], axis=1).max()),
        "truth_mesh": {"tets": int(len(tmd.T)), "nodes": int(len(tmd.X)), "h_fine_m": h_fine, "h_coarse_m": 3 * h_fine},
        "dataset_mesh": {"tets": int(len(dmd.T)), "nodes": int(len(dmd.X)), "h_m": h_ds, "remeshed": remesh},
        "contacts": [{"id": c["id"], "point": c["point"].tolist(), "outward_normal": c["normal"].tolist(),
                      "reported_N": f.tolist(), "true_N": t.tolist()} for c, f, t in zip(contacts, reported, true_f)],
        "truth_newton_iterations": info["newton_iterations"],
        "seconds": time.time() - t_start,
    }
    with open(os.path.join(out, "truth.json"), "w") as fh:
        json.dump(truth_json, fh, indent=1)
    log(f"  SNR {snr_pos:.1f} (displacements {snr:.1f}), RMS displacement {rms_disp * 1e3:.2f} mm, {n_obs} observed entries, {time.time() - t_start:.1f} s -> {out}")
    return truth_json


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-o", "--out", required=True)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--shape", choices=SHAPES)
    ap.add_argument("--effect", choices=EFFECTS)
    ap.add_argument("--quick", action="store_true", help="coarser truth mesh, at most 4 contacts (smoke tests)")
    a = ap.parse_args()
    generate(a.out, a.seed, a.shape, a.effect, a.quick)


if __name__ == "__main__":
    main()
