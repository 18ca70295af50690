//! The force-driven contact rule: how a probe force becomes nodal forces.
//!
//! The thesis probes with a disk (§4.1) and measures one force per contact; it does not say how
//! the force is spread. palpate's rule, shared by the runtime, the fitters and the specimen
//! generator so that all three load the object identically:
//!
//! 1. Candidate nodes are the *surface* nodes (nodes of boundary triangles) that are *not fixed*.
//! 2. A candidate is loaded when its **rest** position lies within the probe radius r of the
//!    contact point c (‖x₀ᵢ − c‖ ≤ r, a ball, so the rule does not need a surface normal).
//! 3. Each loaded node i carries the share A_i / Σ_j A_j of the force vector, A_i being its lumped
//!    surface area: one third of the area of every boundary triangle that touches it. This is a
//!    uniform pressure under the disk, integrated with lumped (nodal) quadrature.
//! 4. No loaded node is an error ([`ContactRuleError::NoNodeInRadius`]).

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

/// Applies the contact rule: calls `emit(node, weight)` for every loaded node, weights summing to
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
