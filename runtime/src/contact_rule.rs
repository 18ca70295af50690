//! The force-driven contact rules: how a probe force becomes nodal forces.
//!
//! The thesis probes with a disk (§4.1) and measures one force per contact; it does not say how
//! the force is spread. palpate has two rules, shared by the runtime, the fitters and the specimen
//! generator so that all of them load the object identically for a given [`ContactRule`]:
//!
//! **Lumped** ([`contact_weights`], the default everywhere; static datasets are fitted and
//! generated with it):
//! 1. Candidate nodes are the *surface* nodes (nodes of boundary triangles) that are *not fixed*.
//! 2. A candidate is loaded when its **rest** position lies within the probe radius r of the
//!    contact point c (‖x₀ᵢ − c‖ ≤ r, a ball, so the rule does not need a surface normal).
//! 3. Each loaded node i carries the share A_i / Σ_j A_j of the force vector, A_i being its lumped
//!    surface area: one third of the area of every boundary triangle that touches it. This is a
//!    uniform pressure under the disk, integrated with lumped (nodal) quadrature.
//! 4. No loaded node is an error ([`ContactRuleError::NoNodeInRadius`]).
//!
//! **Consistent** ([`contact_weights_consistent`], for a probe that *slides*, e.g. the haptic
//! loop): the same uniform pressure over the part of the rest surface inside the ball, integrated
//! consistently (work-equivalent nodal forces f_i = F ∫ N_i dA / ∫ dA):
//! 1. A surface triangle wholly inside the ball gives each of its nodes A_t/3 (∫ N_i exactly).
//! 2. A triangle the rim crosses is integrated on [`RIM_SUBDIVISIONS`]² sub-triangles (centroid
//!    rule, exact for the linear N_i) whose inclusion ramps linearly from 1 to 0 across one
//!    sub-triangle width w = √(2 A_t)/[`RIM_SUBDIVISIONS`] centred on the rim. The inside/outside
//!    shortcuts are taken only when every sample would give 1 or 0, so the nodal forces are a
//!    *continuous* (Lipschitz) function of the contact point and radius.
//! 3. Fixed nodes carry nothing; the free nodes' shares are normalised to sum to one; a ball that
//!    loads no free node is an error.
//!
//! Why two: under the lumped rule the nodal loads jump whenever a node crosses the rim — by ~4 %
//! of the probe force on a 5 mm mesh with a 15 mm probe. A probe sliding over the surface then
//! "pops" (a haptic artefact) and each jump costs the runtime ~20 PCG iterations in one tick
//! (`palpate-lab bench runtime --rule lumped`); the consistent load changes by O(speed) per tick. Away
//! from the rim both give the same loads (A_i/ΣA). Static datasets keep the lumped rule because
//! every dataset, specimen and fit so far was made with it; a model replayed with the consistent
//! rule differs from its fit only at rim nodes.

/// Which rule spreads a force-driven contact (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ContactRule {
    /// Whole nodes within the ball, by lumped area ([`contact_weights`]).
    #[default]
    Lumped,
    /// Uniform pressure integrated consistently, continuous in the contact point
    /// ([`contact_weights_consistent`]).
    Consistent,
}

/// Sub-triangles per edge when a rim-crossing triangle is integrated (64 samples per triangle).
pub const RIM_SUBDIVISIONS: usize = 8;

/// Why a contact could not be spread.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ContactRuleError {
    /// No free surface node lies within the probe radius of the contact point.
    NoNodeInRadius {
        /// Distance from the contact point to the nearest free surface node (m).
        nearest: f64,
    },
    /// Radius or contact point is not finite, or the radius is not positive.
    BadInput,
}

/// Lumped surface area of every node: A_i = Σ_{triangles t ∋ i} area(t) / 3. `areas` must hold
/// one value per node; it is overwritten.
pub fn lumped_surface_areas(
    pos: impl Fn(usize) -> [f64; 3],
    tris: impl IntoIterator<Item = [usize; 3]>,
    areas: &mut [f64],
) {
    areas.iter_mut().for_each(|a| *a = 0.0);
    for t in tris {
        let (a, b, c) = (pos(t[0]), pos(t[1]), pos(t[2]));
        let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let n = [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ];
        let area = 0.5 * libm::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
        for &i in &t {
            if let Some(slot) = areas.get_mut(i) {
                *slot += area / 3.0;
            }
        }
    }
}

/// Applies the lumped rule: calls `emit(node, weight)` for every loaded node, weights summing to
/// one (multiply by the force vector to get nodal forces). Surface nodes are those with a positive
/// lumped area. Returns the number of loaded nodes.
pub fn contact_weights(
    contact: [f64; 3],
    radius: f64,
    pos: impl Fn(usize) -> [f64; 3],
    areas: &[f64],
    is_fixed: impl Fn(usize) -> bool,
    emit: impl FnMut(usize, f64),
) -> Result<usize, ContactRuleError> {
    contact_weights_by(
        contact,
        radius,
        areas.len(),
        pos,
        |i| areas[i],
        is_fixed,
        emit,
    )
}

/// [`contact_weights`] with the lumped areas given by an accessor (the runtime keeps them in
/// `f32` storage), over nodes `0..node_count`.
pub fn contact_weights_by(
    contact: [f64; 3],
    radius: f64,
    node_count: usize,
    pos: impl Fn(usize) -> [f64; 3],
    area: impl Fn(usize) -> f64,
    is_fixed: impl Fn(usize) -> bool,
    mut emit: impl FnMut(usize, f64),
) -> Result<usize, ContactRuleError> {
    if !(radius.is_finite() && radius > 0.0 && contact.iter().all(|v| v.is_finite())) {
        return Err(ContactRuleError::BadInput);
    }
    let dist = |i: usize| {
        let p = pos(i);
        let d = [p[0] - contact[0], p[1] - contact[1], p[2] - contact[2]];
        libm::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    };
    let candidate = |i: usize| area(i) > 0.0 && !is_fixed(i);
    let mut total = 0.0;
    let mut nearest = f64::INFINITY;
    for i in 0..node_count {
        if candidate(i) {
            let d = dist(i);
            nearest = nearest.min(d);
            if d <= radius {
                total += area(i);
            }
        }
    }
    if total <= 0.0 {
        return Err(ContactRuleError::NoNodeInRadius { nearest });
    }
    let mut count = 0;
    for i in 0..node_count {
        if candidate(i) && dist(i) <= radius {
            emit(i, area(i) / total);
            count += 1;
        }
    }
    Ok(count)
}

/// Inclusion of a sample at distance `d` from the contact: 1 inside the rim, 0 outside, linear
/// across the ramp of width `w` centred on the rim.
#[inline(always)]
fn rim_profile(d: f64, radius: f64, w: f64) -> f64 {
    ((radius - d) / w + 0.5).clamp(0.0, 1.0)
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    libm::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
}

/// ∫ N_k · inclusion dA over triangle `v` for its three nodes (consistent rule, steps 1–2); all zero when the
/// triangle is outside the ball.
pub fn triangle_load(v: [[f64; 3]; 3], contact: [f64; 3], radius: f64) -> [f64; 3] {
    let sub = |a: [f64; 3], b: [f64; 3]| [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    let sq = |a: [f64; 3]| a[0] * a[0] + a[1] * a[1] + a[2] * a[2];
    let (u, w) = (sub(v[1], v[0]), sub(v[2], v[0]));
    // Cheap rejection first (most triangles are far from the probe): every point of a triangle
    // lies within its longest edge L of each vertex, and the ramp is at most L/q wide, so the
    // triangle is outside when its farthest vertex is beyond r + L (1 + 1/(2q)). Conservative,
    // so it returns exactly what sampling would (zero).
    let d2 = v.map(|x| sq(sub(x, contact)));
    let l2 = sq(u).max(sq(w)).max(sq(sub(v[2], v[1])));
    let q = RIM_SUBDIVISIONS;
    let reach = radius + libm::sqrt(l2) * (1.0 + 0.5 / q as f64);
    if d2[0].max(d2[1]).max(d2[2]) >= reach * reach {
        return [0.0; 3];
    }
    let n = [
        u[1] * w[2] - u[2] * w[1],
        u[2] * w[0] - u[0] * w[2],
        u[0] * w[1] - u[1] * w[0],
    ];
    let area = 0.5 * libm::sqrt(sq(n));
    // Degenerate (or NaN) area: nothing to load.
    if area.is_nan() || area <= 0.0 {
        return [0.0; 3];
    }
    let ramp = libm::sqrt(2.0 * area) / q as f64;
    let inner = radius - 0.5 * ramp;
    if inner > 0.0 && d2[0].max(d2[1]).max(d2[2]) <= inner * inner {
        // Wholly inside (the ball is convex): every sample would weigh 1.
        return [area / 3.0; 3];
    }
    // Sub-triangle centroids in barycentric (β, γ): q² cells, "up" cells at (i + ⅓, j + ⅓)/q and
    // "down" cells at (i + ⅔, j + ⅔)/q, each of area A/q².
    let cell = area / (q * q) as f64;
    let mut out = [0.0; 3];
    let mut sample = |beta: f64, gamma: f64| {
        let p = [
            v[0][0] + beta * u[0] + gamma * w[0],
            v[0][1] + beta * u[1] + gamma * w[1],
            v[0][2] + beta * u[2] + gamma * w[2],
        ];
        let s = rim_profile(libm::sqrt(sq(sub(p, contact))), radius, ramp) * cell;
        if s > 0.0 {
            out[0] += s * (1.0 - beta - gamma);
            out[1] += s * beta;
            out[2] += s * gamma;
        }
    };
    let qf = q as f64;
    for i in 0..q {
        for j in 0..q - i {
            sample((i as f64 + 1.0 / 3.0) / qf, (j as f64 + 1.0 / 3.0) / qf);
            if i + j + 1 < q {
                sample((i as f64 + 2.0 / 3.0) / qf, (j as f64 + 2.0 / 3.0) / qf);
            }
        }
    }
    out
}

/// One pass of the contact rule without normalisation: calls `emit(node, ∫ N_i dA)` for every
/// free node of every loaded surface triangle (a node can be emitted several times: callers
/// **add**) and returns (Σ of the emitted integrals, loaded triangles). `tri(k)` gives surface
/// triangle k of `tri_count`; a triangle with a node id ≥ `node_count` is skipped. The weights
/// of [`contact_weights_consistent`] are these integrals divided by the sum.
///
/// Not inlined: kept out of its callers so the haptic tick's contact command compiles as it
/// did before the runtime's rooms redesign (inlined, the per-tick force command measured ~3 %
/// slower on the 5k-tet bench).
#[allow(clippy::too_many_arguments)]
#[inline(never)]
pub fn contact_integrals(
    contact: [f64; 3],
    radius: f64,
    node_count: usize,
    pos: impl Fn(usize) -> [f64; 3],
    tri_count: usize,
    tri: impl Fn(usize) -> [usize; 3],
    is_fixed: impl Fn(usize) -> bool,
    mut emit: impl FnMut(usize, f64),
) -> Result<(f64, usize), ContactRuleError> {
    if !(radius.is_finite() && radius > 0.0 && contact.iter().all(|v| v.is_finite())) {
        return Err(ContactRuleError::BadInput);
    }
    let mut total = 0.0;
    let mut count = 0;
    for k in 0..tri_count {
        let t = tri(k);
        if t.iter().any(|&i| i >= node_count) {
            continue;
        }
        let l = triangle_load(t.map(&pos), contact, radius);
        let mut loaded = false;
        for (&i, lk) in t.iter().zip(l) {
            if lk > 0.0 && !is_fixed(i) {
                emit(i, lk);
                total += lk;
                loaded = true;
            }
        }
        count += loaded as usize;
    }
    if total.is_nan() || total <= 0.0 {
        // Only now look for the nearest free surface node, for the error message.
        let mut nearest = f64::INFINITY;
        for k in 0..tri_count {
            for i in tri(k) {
                if i < node_count && !is_fixed(i) {
                    nearest = nearest.min(dist(pos(i), contact));
                }
            }
        }
        return Err(ContactRuleError::NoNodeInRadius { nearest });
    }
    Ok((total, count))
}

/// Applies the consistent rule (module docs): calls `emit(node, weight)` for every free node of
/// every loaded surface triangle (a node can be emitted several times: callers **add**), the
/// weights summing to one over all calls; multiply by the force vector to get nodal forces.
/// Arguments as [`contact_integrals`]. Returns the number of loaded triangles.
#[allow(clippy::too_many_arguments)]
pub fn contact_weights_consistent(
    contact: [f64; 3],
    radius: f64,
    node_count: usize,
    pos: impl Fn(usize) -> [f64; 3],
    tri_count: usize,
    tri: impl Fn(usize) -> [usize; 3],
    is_fixed: impl Fn(usize) -> bool,
    mut emit: impl FnMut(usize, f64),
) -> Result<usize, ContactRuleError> {
    let (total, count) = contact_integrals(
        contact,
        radius,
        node_count,
        &pos,
        tri_count,
        &tri,
        &is_fixed,
        |_, _| {},
    )?;
    contact_integrals(
        contact,
        radius,
        node_count,
        pos,
        tri_count,
        tri,
        is_fixed,
        |i, l| emit(i, l / total),
    )?;
    Ok(count)
}
