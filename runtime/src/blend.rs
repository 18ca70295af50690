//! Run-time blending of fitted parameter sets for non-linear materials (seed 000 §6.2.3–6.2.4).
//!
//! Biharmonic RBFs φ(r) = r interpolate each fitted set exactly at its own centre. Outside the
//! fitted range RBFs extrapolate badly (the thesis warns of it), so the blended (λ, α) are clamped
//! to the range spanned by the fitted sets (per element for per-element sets), and α is then kept
//! inside the physical band −0.999 λ < α < 0.499 λ. The runtime therefore never leaves the
//! convex range of what was measured.

use crate::element_state::ElementState;
use crate::nodes::NodeState;
use palpate_protocol::model::{Blend, ModelRecord, ParameterLayout};

/// Biharmonic basis φ(r) = r (eqs. 6.2–6.5).
#[inline(always)]
pub fn phi(r: f32) -> f32 {
    r
}

/// Recomputes (λ_e, α_e) of `elements` from the current state — the node positions for
/// deformation-space blending, the element strains for strain-space blending — (no-op for
/// linear materials). Returns the largest change of an element's parameters relative to its λ_e
/// before, max_e max(|Δλ_e|, |Δα_e|) / λ_e: how far K_e moved (relatively), which the
/// preconditioner's refresh rule adds to the rotations' drift.
pub(crate) fn blend_parameters(
    rec: &ModelRecord<'_>,
    nodes: &NodeState<'_>,
    elements: &mut ElementState<'_>,
) -> f32 {
    let ps = rec.parameters;
    let sets = ps.count as usize;
    let per_element = ps.layout == ParameterLayout::PerElement;
    let t = elements.t;
    let set_value = |arr: &palpate_protocol::model::F32s<'_>, s: usize, e: usize| -> f32 {
        arr.get(if per_element { s * t + e } else { s })
            .unwrap_or(0.0)
    };
    // Element e's blended (λ, α), clamped to the range of its fitted sets, into `elements`.
    let mut change = 0.0f32;
    let mut store = |elements: &mut ElementState<'_>, e: usize, lam: f32, alp: f32| {
        let (l, a) = clamp_to_sets(
            lam,
            alp,
            sets,
            |s| set_value(&ps.lambda, s, e),
            |s| set_value(&ps.alpha, s, e),
        );
        let (l0, a0) = (elements.lam[e], elements.alp[e]);
        let moved = (l - l0).abs().max((a - a0).abs()) / l0;
        // A first blend (λ₀ = 0) or a non-finite ratio counts as a full change.
        change = change.max(if moved.is_finite() {
            moved
        } else {
            f32::INFINITY
        });
        elements.lam[e] = l;
        elements.alp[e] = a;
    };
    match rec.blend {
        Blend::None => {}
        Blend::Deformation {
            centres,
            weights_lambda,
            weights_alpha,
        } => {
            // λ = Σ_i w_i^λ φ(‖x − x̄_i‖) (eq. 6.2), α likewise (eq. 6.3); x over all nodes.
            let mut lam = 0.0f32;
            let mut alp = 0.0f32;
            let n3 = 3 * nodes.n;
            for s in 0..sets {
                let mut d2 = 0.0f64;
                for k in 0..n3 {
                    let x = nodes.x0[k] + nodes.u[k];
                    let c = centres.get(s * n3 + k).unwrap_or(x);
                    d2 += ((x - c) as f64) * ((x - c) as f64);
                }
                let ph = phi(libm::sqrt(d2) as f32);
                lam += weights_lambda.get(s).unwrap_or(0.0) * ph;
                alp += weights_alpha.get(s).unwrap_or(0.0) * ph;
            }
            for e in 0..t {
                store(elements, e, lam, alp);
            }
        }
        Blend::Strain {
            neighbours,
            neighbour_index,
            neighbour_weight,
            centres,
            weights_lambda,
            weights_alpha,
            ..
        } => {
            // λ_e = Σ_l w_{e,l}^λ φ(‖e − ē_l‖_e) (eqs. 6.9–6.11) with the locally weighted metric
            // ‖e − ē_l‖²_e = Σ_j w_{e,j} ‖ε_j − ē_{l,j}‖² over e's neighbours j. A neighbour's
            // distance depends on (l, j) only, so it is computed once per element and set
            // (`strain_distance`) rather than once per element that lists it (k times), and
            // stored element-major (`j · sets + l`) so that a neighbour's distances to every set
            // are read together: each neighbour's index and weight are then decoded once per
            // element instead of once per set (the strain-space tick's blend was mostly these
            // decodes).
            let k = neighbours as usize;
            for l in 0..sets {
                for j in 0..t {
                    let mut s2 = 0.0f32;
                    for c in 0..6 {
                        let cur = elements.strain.get(6 * j + c).copied().unwrap_or(0.0);
                        let cen = centres.get((l * t + j) * 6 + c).unwrap_or(cur);
                        s2 += (cur - cen) * (cur - cen);
                    }
                    if let Some(d) = elements.strain_distance.get_mut(j * sets + l) {
                        *d = s2;
                    }
                }
            }
            // Sets are accumulated a chunk at a time in registers; each set's sum runs over the
            // neighbours in the same order as one set at a time would.
            for e in 0..t {
                let mut lam = 0.0f32;
                let mut alp = 0.0f32;
                for first in (0..sets).step_by(CHUNK) {
                    let width = CHUNK.min(sets - first);
                    let sums = NeighbourSums {
                        index: &neighbour_index,
                        weight: &neighbour_weight,
                        distance: elements.strain_distance,
                        e,
                        k,
                        t,
                        sets,
                        first,
                    };
                    let d2 = sums.chunk(width);
                    for (c, &d) in d2[..width].iter().enumerate() {
                        let l = first + c;
                        let ph = phi(libm::sqrtf(d.max(0.0)));
                        lam += weights_lambda.get(e * sets + l).unwrap_or(0.0) * ph;
                        alp += weights_alpha.get(e * sets + l).unwrap_or(0.0) * ph;
                    }
                }
                store(elements, e, lam, alp);
            }
        }
    }
    change
}

/// Sets whose neighbour sums one pass accumulates together.
const CHUNK: usize = 8;

/// One element's neighbour-weighted distances to a run of fitted sets (eq. 6.10):
/// Σ_j w_{e,j} ‖ε_j − ē_{l,j}‖² over e's neighbours j, for the sets `first..first + width`.
struct NeighbourSums<'r, 'a> {
    index: &'r palpate_protocol::model::U32s<'a>,
    weight: &'r palpate_protocol::model::F32s<'a>,
    /// ‖ε_j − ē_{l,j}‖² at `j · sets + l`.
    distance: &'r [f32],
    e: usize,
    k: usize,
    t: usize,
    sets: usize,
    first: usize,
}

impl NeighbourSums<'_, '_> {
    /// The sums of `width` (1..=CHUNK) sets, zero-padded to CHUNK.
    ///
    /// The width is made a constant first: with a run-time width the sums lived in a stack
    /// array, a store and a reload per neighbour and set (most of the strain-space blend's
    /// time in `perf annotate`); with a constant one they stay in registers. The same sums in
    /// the same order either way.
    fn chunk(&self, width: usize) -> [f32; CHUNK] {
        match width {
            1 => pad(self.sums::<1>()),
            2 => pad(self.sums::<2>()),
            3 => pad(self.sums::<3>()),
            4 => pad(self.sums::<4>()),
            5 => pad(self.sums::<5>()),
            6 => pad(self.sums::<6>()),
            7 => pad(self.sums::<7>()),
            _ => pad(self.sums::<CHUNK>()),
        }
    }

    #[inline(always)]
    fn sums<const W: usize>(&self) -> [f32; W] {
        let mut d2 = [0.0f32; W];
        for j in 0..self.k {
            let at = self.e * self.k + j;
            let nb = self.index.get(at).unwrap_or(self.e as u32) as usize;
            let w = self.weight.get(at).unwrap_or(0.0);
            if nb >= self.t {
                continue;
            }
            let start = nb * self.sets + self.first;
            if let Some(row) = self.distance.get(start..start + W) {
                for c in 0..W {
                    d2[c] += w * row[c];
                }
            }
        }
        d2
    }
}

/// `d` followed by zeros.
#[inline(always)]
fn pad<const W: usize>(d: [f32; W]) -> [f32; CHUNK] {
    let mut o = [0.0f32; CHUNK];
    for (o, d) in o.iter_mut().zip(d) {
        *o = d;
    }
    o
}

/// Clamps blended (λ, α) to the range of the fitted sets and to the physical band.
fn clamp_to_sets(
    lam: f32,
    alp: f32,
    sets: usize,
    set_lambda: impl Fn(usize) -> f32,
    set_alpha: impl Fn(usize) -> f32,
) -> (f32, f32) {
    let (mut lo_l, mut hi_l, mut lo_a, mut hi_a) = (
        f32::INFINITY,
        f32::NEG_INFINITY,
        f32::INFINITY,
        f32::NEG_INFINITY,
    );
    for s in 0..sets {
        let (l, a) = (set_lambda(s), set_alpha(s));
        lo_l = lo_l.min(l);
        hi_l = hi_l.max(l);
        lo_a = lo_a.min(a);
        hi_a = hi_a.max(a);
    }
    let l = if lam.is_finite() {
        lam.clamp(lo_l, hi_l)
    } else {
        set_lambda(0)
    };
    let a = if alp.is_finite() {
        alp.clamp(lo_a, hi_a)
    } else {
        set_alpha(0)
    };
    (l, a.clamp(-0.999 * l, 0.499 * l))
}

#[cfg(test)]
mod tests {
    use super::*;
    use palpate_protocol::model::{F32s, U32s};

    /// Every constant width sums the same neighbours and sets in the same order as a loop over a
    /// run-time width — to the last bit — for 11 sets read from three offsets (chunks of 8, 3 and
    /// the widths between), with neighbour indices past the element count skipped.
    #[test]
    fn neighbour_sums_match_a_plain_loop_for_every_width() {
        let (t, k, sets) = (5usize, 3usize, 11usize);
        // (i · 7 + 3) mod 6 reaches 5 = t: an out-of-range neighbour, which the sums skip.
        let index: Vec<u32> = (0..t * k).map(|i| ((i * 7 + 3) % (t + 1)) as u32).collect();
        let weight: Vec<f32> = (0..t * k).map(|i| 0.1 + 0.37 * i as f32).collect();
        let distance: Vec<f32> = (0..t * sets)
            .map(|i| (i as f32 * 0.731).sin().abs())
            .collect();
        let ib: Vec<u8> = index.iter().flat_map(|v| v.to_le_bytes()).collect();
        let wb: Vec<u8> = weight.iter().flat_map(|v| v.to_le_bytes()).collect();
        let (iu, wf) = (U32s(&ib), F32s(&wb));
        assert!(index.iter().any(|&i| i as usize >= t));
        for e in 0..t {
            for first in [0, 3, 8] {
                for width in 1..=CHUNK.min(sets - first) {
                    let got = NeighbourSums {
                        index: &iu,
                        weight: &wf,
                        distance: &distance,
                        e,
                        k,
                        t,
                        sets,
                        first,
                    }
                    .chunk(width);
                    let mut want = [0.0f32; CHUNK];
                    for j in 0..k {
                        let nb = index[e * k + j] as usize;
                        if nb >= t {
                            continue;
                        }
                        for c in 0..width {
                            want[c] += weight[e * k + j] * distance[nb * sets + first + c];
                        }
                    }
                    assert_eq!(got, want, "element {e}, sets {first}..{}", first + width);
                }
            }
        }
    }
}
