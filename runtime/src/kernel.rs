//! The per-element hot kernels of the warped stiffness, matrix-free.
//!
//! For an isotropic element E = λF + αG (eq. 3.38) the stress of a displacement gradient H is
//! σ = α tr(ε) I + (λ − 2α) ε with ε = sym(H) (α is Lamé's first constant, λ − 2α = 2μ). The
//! element force is f_a = V_e σ ∇φ_a, which is exactly K_e u_e = V_e B_eᵀ E B_e u_e (eq. 3.21) —
//! the same matrix as λ C_e + α D_e, evaluated without forming it. Warping (eqs. 3.50–3.53)
//! rotates the gradient into the rest frame (Rᵀ H) and the stress back (R σ).
//!
//! Data per element, structure-of-arrays: `grad` holds ∇φ_1..∇φ_3 (∇φ_0 = −Σ), 9 values;
//! `rot` holds R_e row-major, 9 values.

/// 3 × 3 row-major matrix.
pub type M3 = [f32; 9];

/// H = Σ_{a=1..3} (v_a − v_0) ⊗ ∇φ_a, row-major (H_ij = Σ_a (v_a − v_0)_i ∇φ_a,j).
#[inline(always)]
pub fn gradient_of(v: &[[f32; 3]; 4], g: &[f32; 9]) -> M3 {
    let mut h = [0.0f32; 9];
    for a in 0..3 {
        let d = [
            v[a + 1][0] - v[0][0],
            v[a + 1][1] - v[0][1],
            v[a + 1][2] - v[0][2],
        ];
        let ga = [g[3 * a], g[3 * a + 1], g[3 * a + 2]];
        for i in 0..3 {
            for j in 0..3 {
                h[3 * i + j] += d[i] * ga[j];
            }
        }
    }
    h
}

/// Rᵀ H.
#[inline(always)]
pub fn rt_mul(r: &M3, h: &M3) -> M3 {
    let mut o = [0.0f32; 9];
    for i in 0..3 {
        for j in 0..3 {
            o[3 * i + j] = r[i] * h[j] + r[3 + i] * h[3 + j] + r[6 + i] * h[6 + j];
        }
    }
    o
}

/// R S.
#[inline(always)]
pub fn r_mul(r: &M3, s: &M3) -> M3 {
    let mut o = [0.0f32; 9];
    for i in 0..3 {
        for j in 0..3 {
            o[3 * i + j] = r[3 * i] * s[j] + r[3 * i + 1] * s[3 + j] + r[3 * i + 2] * s[6 + j];
        }
    }
    o
}

/// σ(H) = α tr(ε) I + (λ − 2α) ε, ε = sym(H) (symmetric, row-major).
#[inline(always)]
pub fn stress(h: &M3, lambda: f32, alpha: f32) -> M3 {
    let two_mu = lambda - 2.0 * alpha;
    let tr = h[0] + h[4] + h[8];
    let s01 = 0.5 * two_mu * (h[1] + h[3]);
    let s02 = 0.5 * two_mu * (h[2] + h[6]);
    let s12 = 0.5 * two_mu * (h[5] + h[7]);
    [
        alpha * tr + two_mu * h[0],
        s01,
        s02,
        s01,
        alpha * tr + two_mu * h[4],
        s12,
        s02,
        s12,
        alpha * tr + two_mu * h[8],
    ]
}

/// Nodal forces f_a = P ∇φ_a (a = 1..3), f_0 = −Σ f_a, for P = V R σ.
#[inline(always)]
pub fn nodal_forces(p: &M3, g: &[f32; 9]) -> [[f32; 3]; 4] {
    let mut f = [[0.0f32; 3]; 4];
    for a in 0..3 {
        for i in 0..3 {
            let v = p[3 * i] * g[3 * a] + p[3 * i + 1] * g[3 * a + 1] + p[3 * i + 2] * g[3 * a + 2];
            f[a + 1][i] = v;
            f[0][i] -= v;
        }
    }
    f
}

/// Warped element stiffness times a displacement: R K_e Rᵀ v_e.
#[inline(always)]
pub fn warped_apply(
    v: &[[f32; 3]; 4],
    g: &[f32; 9],
    r: &M3,
    volume: f32,
    lambda: f32,
    alpha: f32,
) -> [[f32; 3]; 4] {
    let h = rt_mul(r, &gradient_of(v, g));
    rest_frame_forces(&h, g, r, volume, lambda, alpha)
}

/// Warped internal force R K_e (Rᵀ x_e − x_0e) from the deformation gradient F = I + H(u):
/// the rest-frame displacement gradient is Rᵀ F − I (eq. 3.49 in gradient form).
/// Also returns the rest-frame strain tensor sym(RᵀF) − I (for strain-space blending).
#[inline(always)]
pub fn warped_internal_force(
    u: &[[f32; 3]; 4],
    g: &[f32; 9],
    r: &M3,
    volume: f32,
    lambda: f32,
    alpha: f32,
) -> ([[f32; 3]; 4], M3) {
    let mut f = gradient_of(u, g);
    f[0] += 1.0;
    f[4] += 1.0;
    f[8] += 1.0;
    let mut h = rt_mul(r, &f);
    h[0] -= 1.0;
    h[4] -= 1.0;
    h[8] -= 1.0;
    (rest_frame_forces(&h, g, r, volume, lambda, alpha), h)
}

/// Nodal forces of a rest-frame displacement gradient Ĥ: f_a = V R σ(Ĥ) ∇φ_a, the stress
/// rotated back to the world (eq. 3.53).
#[inline(always)]
fn rest_frame_forces(
    h: &M3,
    g: &[f32; 9],
    r: &M3,
    volume: f32,
    lambda: f32,
    alpha: f32,
) -> [[f32; 3]; 4] {
    let s = stress(h, lambda, alpha);
    let mut p = r_mul(r, &s);
    p.iter_mut().for_each(|x| *x *= volume);
    nodal_forces(&p, g)
}

/// Diagonal 3 × 3 block of R K_e Rᵀ for node `a` (0..4), packed (xx, yy, zz, xy, yz, zx):
/// V [ (λ/2) (R∇φ_a)(R∇φ_a)ᵀ + μ |∇φ_a|² I ], μ = λ/2 − α.
#[inline(always)]
pub fn diagonal_block(
    a: usize,
    g: &[f32; 9],
    r: &M3,
    volume: f32,
    lambda: f32,
    alpha: f32,
) -> [f32; 6] {
    let ga = if a == 0 {
        [
            -(g[0] + g[3] + g[6]),
            -(g[1] + g[4] + g[7]),
            -(g[2] + g[5] + g[8]),
        ]
    } else {
        [g[3 * (a - 1)], g[3 * (a - 1) + 1], g[3 * (a - 1) + 2]]
    };
    let rg = [
        r[0] * ga[0] + r[1] * ga[1] + r[2] * ga[2],
        r[3] * ga[0] + r[4] * ga[1] + r[5] * ga[2],
        r[6] * ga[0] + r[7] * ga[1] + r[8] * ga[2],
    ];
    let half = 0.5 * lambda * volume;
    let iso = (0.5 * lambda - alpha) * volume * (ga[0] * ga[0] + ga[1] * ga[1] + ga[2] * ga[2]);
    [
        half * rg[0] * rg[0] + iso,
        half * rg[1] * rg[1] + iso,
        half * rg[2] * rg[2] + iso,
        half * rg[0] * rg[1],
        half * rg[1] * rg[2],
        half * rg[2] * rg[0],
    ]
}

/// Warped element stiffness times a displacement using the packed C_e, D_e of the model
/// (eq. 3.63): R (λ C_e + α D_e) Rᵀ v_e. The alternative kernel, compared by `bench runtime`.
#[inline(always)]
pub fn warped_apply_packed(
    v: &[[f32; 3]; 4],
    c: &[f32; 78],
    d: &[f32; 78],
    r: &M3,
    lambda: f32,
    alpha: f32,
) -> [[f32; 3]; 4] {
    let mut w = [0.0f32; 12];
    for a in 0..4 {
        for i in 0..3 {
            w[3 * a + i] = r[i] * v[a][0] + r[3 + i] * v[a][1] + r[6 + i] * v[a][2];
        }
    }
    let mut y = [0.0f32; 12];
    let mut k = 0;
    for i in 0..12 {
        let kii = lambda * c[k] + alpha * d[k];
        y[i] += kii * w[i];
        k += 1;
        for j in (i + 1)..12 {
            let kij = lambda * c[k] + alpha * d[k];
            y[i] += kij * w[j];
            y[j] += kij * w[i];
            k += 1;
        }
    }
    let mut out = [[0.0f32; 3]; 4];
    for a in 0..4 {
        for i in 0..3 {
            out[a][i] =
                r[3 * i] * y[3 * a] + r[3 * i + 1] * y[3 * a + 1] + r[3 * i + 2] * y[3 * a + 2];
        }
    }
    out
}

/// a · b with `LANES` independent partial sums, so the reduction vectorises (a single running
/// sum is a serial chain of dependent adds, one per 4 cycles). Lengths must match (extra
/// entries of the longer slice are ignored).
#[inline]
pub fn dot_lanes(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0.0f32; LANES];
    let (ca, cb) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        for l in 0..LANES {
            acc[l] += x[l] * y[l];
        }
    }
    let mut s = 0.0f32;
    for (x, y) in ra.iter().zip(rb) {
        s += x * y;
    }
    acc.iter().sum::<f32>() + s
}

/// ‖v‖² accumulated in f64 with `LANES` independent partial sums (see [`dot_lanes`]).
#[inline]
pub fn norm2_lanes(v: &[f32]) -> f64 {
    let mut acc = [0.0f64; LANES];
    let c = v.chunks_exact(LANES);
    let rest = c.remainder();
    for x in c {
        for l in 0..LANES {
            acc[l] += (x[l] as f64) * (x[l] as f64);
        }
    }
    let mut s = 0.0f64;
    for x in rest {
        s += (*x as f64) * (*x as f64);
    }
    acc.iter().sum::<f64>() + s
}

/// Lanes of the batched kernel: eight elements at once, structure-of-arrays, so the arithmetic
/// compiles to 8-wide SIMD (AVX2) or 2 × 4-wide (SSE2 / NEON) without target-specific code.
pub const LANES: usize = 8;

/// Batched R K_e Rᵀ v_e from the *rotated* gradients ĝ_a = R ∇φ_a (a = 1..3): with
/// M = Σ_a (v_a − v_0) ĝ_aᵀ = H Rᵀ, the warped force is f_a = V σ(M) ĝ_a, because for the
/// isotropic σ(ε) = α tr(ε) I + 2μ ε one has R σ(sym(RᵀH)) Rᵀ = σ(sym(H Rᵀ)). The same operator
/// as [`warped_apply`], lane by lane, without the two 3 × 3 rotation products (a third of the work of a
/// PCG iteration's element pass).
#[inline(always)]
#[allow(clippy::needless_range_loop)]
pub fn rotated_apply_lanes(
    v: &[[[f32; LANES]; 3]; 4],
    gh: &[[f32; LANES]; 9],
    volume: &[f32; LANES],
    lambda: &[f32; LANES],
    alpha: &[f32; LANES],
) -> [[[f32; LANES]; 3]; 4] {
    let m = gradient_of_lanes(v, gh);
    let p = scaled_stress_lanes(&m, volume, lambda, alpha);
    nodal_forces_lanes(&p, gh)
}

/// ĝ_a = R ∇φ_a (a = 1..3) lane by lane, the input of [`rotated_apply_lanes`].
#[inline(always)]
#[allow(clippy::needless_range_loop)]
pub fn rotate_gradients_lanes(g: &[[f32; LANES]; 9], r: &[[f32; LANES]; 9]) -> [[f32; LANES]; 9] {
    let mut o = [[0.0f32; LANES]; 9];
    for a in 0..3 {
        for i in 0..3 {
            for l in 0..LANES {
                o[3 * a + i][l] = r[3 * i][l] * g[3 * a][l]
                    + r[3 * i + 1][l] * g[3 * a + 1][l]
                    + r[3 * i + 2][l] * g[3 * a + 2][l];
            }
        }
    }
    o
}

/// [`gradient_of`] lane by lane: H = Σ_a (v_a − v_0) ⊗ ∇φ_a.
#[inline(always)]
#[allow(clippy::needless_range_loop)]
pub fn gradient_of_lanes(v: &[[[f32; LANES]; 3]; 4], g: &[[f32; LANES]; 9]) -> [[f32; LANES]; 9] {
    let mut h = [[0.0f32; LANES]; 9];
    for a in 0..3 {
        for i in 0..3 {
            for j in 0..3 {
                for l in 0..LANES {
                    h[3 * i + j][l] += (v[a + 1][i][l] - v[0][i][l]) * g[3 * a + j][l];
                }
            }
        }
    }
    h
}

/// [`diagonal_block`] for the four nodes of [`LANES`] elements: `out[a][j][l]` is entry j
/// (xx, yy, zz, xy, yz, zx) of node a's block in lane l.
#[inline(always)]
#[allow(clippy::needless_range_loop)]
pub fn diagonal_blocks_lanes(
    g: &[[f32; LANES]; 9],
    r: &[[f32; LANES]; 9],
    volume: &[f32; LANES],
    lambda: &[f32; LANES],
    alpha: &[f32; LANES],
) -> [[[f32; LANES]; 6]; 4] {
    let mut out = [[[0.0f32; LANES]; 6]; 4];
    for a in 0..4 {
        for l in 0..LANES {
            let ga = if a == 0 {
                [
                    -(g[0][l] + g[3][l] + g[6][l]),
                    -(g[1][l] + g[4][l] + g[7][l]),
                    -(g[2][l] + g[5][l] + g[8][l]),
                ]
            } else {
                let b = 3 * (a - 1);
                [g[b][l], g[b + 1][l], g[b + 2][l]]
            };
            let rg = [
                r[0][l] * ga[0] + r[1][l] * ga[1] + r[2][l] * ga[2],
                r[3][l] * ga[0] + r[4][l] * ga[1] + r[5][l] * ga[2],
                r[6][l] * ga[0] + r[7][l] * ga[1] + r[8][l] * ga[2],
            ];
            let half = 0.5 * lambda[l] * volume[l];
            let iso = (0.5 * lambda[l] - alpha[l])
                * volume[l]
                * (ga[0] * ga[0] + ga[1] * ga[1] + ga[2] * ga[2]);
            out[a][0][l] = half * rg[0] * rg[0] + iso;
            out[a][1][l] = half * rg[1] * rg[1] + iso;
            out[a][2][l] = half * rg[2] * rg[2] + iso;
            out[a][3][l] = half * rg[0] * rg[1];
            out[a][4][l] = half * rg[1] * rg[2];
            out[a][5][l] = half * rg[2] * rg[0];
        }
    }
    out
}

/// [`warped_internal_force`] lane by lane, from the displacement gradient
/// H = Σ_a (u_a − u_0) ⊗ ∇φ_a already formed (the fused rotation-and-residual pass needs H for
/// the rotation first): the rest-frame gradient is Rᵀ(I + H) − I.
#[inline(always)]
#[allow(clippy::needless_range_loop)]
pub fn warped_internal_force_from_h_lanes(
    h: &[[f32; LANES]; 9],
    g: &[[f32; LANES]; 9],
    r: &[[f32; LANES]; 9],
    volume: &[f32; LANES],
    lambda: &[f32; LANES],
    alpha: &[f32; LANES],
) -> [[[f32; LANES]; 3]; 4] {
    // Ĥ = Rᵀ H
    let mut hh = [[0.0f32; LANES]; 9];
    for i in 0..3 {
        for j in 0..3 {
            for l in 0..LANES {
                hh[3 * i + j][l] =
                    r[i][l] * h[j][l] + r[3 + i][l] * h[3 + j][l] + r[6 + i][l] * h[6 + j][l];
            }
        }
    }
    // Rᵀ(I + H) − I = RᵀH + Rᵀ − I
    for i in 0..3 {
        for j in 0..3 {
            let delta = if i == j { 1.0 } else { 0.0 };
            for l in 0..LANES {
                hh[3 * i + j][l] += r[3 * j + i][l] - delta;
            }
        }
    }
    // σ = α tr(ε) I + (λ − 2α) ε (unscaled: the volume comes in with R below)
    let s = scaled_stress_lanes(&hh, &[1.0; LANES], lambda, alpha);
    // P = V R σ
    let mut p = [[0.0f32; LANES]; 9];
    for i in 0..3 {
        for j in 0..3 {
            for l in 0..LANES {
                p[3 * i + j][l] = volume[l]
                    * (r[3 * i][l] * s[j][l]
                        + r[3 * i + 1][l] * s[3 + j][l]
                        + r[3 * i + 2][l] * s[6 + j][l]);
            }
        }
    }
    nodal_forces_lanes(&p, g)
}

/// [`stress`] lane by lane, each lane times `scale`: `scale · σ(m)`. The rotated kernel passes
/// the volumes (P = V σ), the warped one ones — `1.0 · x` is exact, so both keep the products
/// they had when each wrote this loop itself.
#[inline(always)]
#[allow(clippy::needless_range_loop)]
fn scaled_stress_lanes(
    m: &[[f32; LANES]; 9],
    scale: &[f32; LANES],
    lambda: &[f32; LANES],
    alpha: &[f32; LANES],
) -> [[f32; LANES]; 9] {
    let mut p = [[0.0f32; LANES]; 9];
    for l in 0..LANES {
        let two_mu = lambda[l] - 2.0 * alpha[l];
        let tr = m[0][l] + m[4][l] + m[8][l];
        let k = scale[l];
        let s01 = k * 0.5 * two_mu * (m[1][l] + m[3][l]);
        let s02 = k * 0.5 * two_mu * (m[2][l] + m[6][l]);
        let s12 = k * 0.5 * two_mu * (m[5][l] + m[7][l]);
        p[0][l] = k * (alpha[l] * tr + two_mu * m[0][l]);
        p[4][l] = k * (alpha[l] * tr + two_mu * m[4][l]);
        p[8][l] = k * (alpha[l] * tr + two_mu * m[8][l]);
        p[1][l] = s01;
        p[3][l] = s01;
        p[2][l] = s02;
        p[6][l] = s02;
        p[5][l] = s12;
        p[7][l] = s12;
    }
    p
}

/// [`nodal_forces`] lane by lane: f_a = P ĝ_a (a = 1..3), f_0 = −Σ f_a.
#[inline(always)]
#[allow(clippy::needless_range_loop)]
fn nodal_forces_lanes(p: &[[f32; LANES]; 9], g: &[[f32; LANES]; 9]) -> [[[f32; LANES]; 3]; 4] {
    let mut f = [[[0.0f32; LANES]; 3]; 4];
    for a in 0..3 {
        for i in 0..3 {
            for l in 0..LANES {
                let val = p[3 * i][l] * g[3 * a][l]
                    + p[3 * i + 1][l] * g[3 * a + 1][l]
                    + p[3 * i + 2][l] * g[3 * a + 2][l];
                f[a + 1][i][l] = val;
                f[0][i][l] -= val;
            }
        }
    }
    f
}
