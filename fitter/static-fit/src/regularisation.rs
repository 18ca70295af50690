//! Smoothness operators and the choice of γ (seed 000 §5.1–5.2).
//!
//! - L_s (§5.2.1, Fig. 5.2): one row per pair of face-neighbouring elements (e, e'), +1 at e and
//!   −1 at e', so γ_s → ∞ forces neighbouring parameters equal.
//! - L_m (eqs. 5.49, 5.57): one row per element (or one for a homogeneous set) and pair of
//!   consecutive measurements (i, i+1), +1 at set i and −1 at set i+1.
//! - The L-curve (§5.1, Fig. 5.1): the data residual against the roughness over a log grid of γ;
//!   the chosen γ is the corner, the point of largest curvature of (log ρ, log η).

use palpate_fem::forward::Material;
use palpate_fem::mesh::Mesh;

/// Pairs of face-neighbouring elements: the rows of L_s.
pub fn spatial_pairs(tets: &[[usize; 4]]) -> Vec<(usize, usize)> {
    let m = Mesh {
        tets: tets.to_vec(),
        ..Default::default()
    };
    m.face_neighbours()
}

/// ‖L_s v‖ for a per-element field `v` (or 0 for a single value).
pub fn roughness(pairs: &[(usize, usize)], v: &[f64]) -> f64 {
    if v.len() <= 1 {
        return 0.0;
    }
    pairs
        .iter()
        .map(|&(a, b)| (v[a] - v[b]).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// The roughness a fit reports: Σ over the parameter sets of ‖L_s λ‖ and of ‖L_s α‖, as
/// [λ, α]. Homogeneous sets (`per_element` false) have none, and no pairs are formed for them.
pub fn sets_roughness(tets: &[[usize; 4]], per_element: bool, sets: &[Material]) -> [f64; 2] {
    let pairs = if per_element {
        spatial_pairs(tets)
    } else {
        Vec::new()
    };
    sets.iter().fold([0.0, 0.0], |acc, m| {
        [
            acc[0] + roughness(&pairs, &m.lambda),
            acc[1] + roughness(&pairs, &m.alpha),
        ]
    })
}

/// Index of the L-curve corner: the interior point with the largest signed curvature (Menger
/// curvature of consecutive triples) of the curve (log ρ, log η), ρ = data residual, η =
/// roughness, points ordered by increasing γ. Falls back to the middle point if the curve is
/// degenerate (fewer than three points, or flat).
pub fn l_curve_corner(points: &[(f64, f64)]) -> usize {
    if points.len() < 3 {
        return points.len() / 2;
    }
    let lp: Vec<(f64, f64)> = points
        .iter()
        .map(|&(r, e)| (r.max(1e-300).ln(), e.max(1e-300).ln()))
        .collect();
    let mut best = (f64::NEG_INFINITY, points.len() / 2);
    for k in 1..lp.len() - 1 {
        let (a, b, c) = (lp[k - 1], lp[k], lp[k + 1]);
        let cross = (b.0 - a.0) * (c.1 - b.1) - (b.1 - a.1) * (c.0 - b.0);
        let d = |p: (f64, f64), q: (f64, f64)| ((p.0 - q.0).powi(2) + (p.1 - q.1).powi(2)).sqrt();
        let denom = d(a, b) * d(b, c) * d(a, c);
        if denom <= 1e-300 {
            continue;
        }
        // As γ grows ρ increases and η decreases; a corner bends "inward", which with this point
        // order gives a positive cross product.
        let kappa = 2.0 * cross / denom;
        if kappa.is_finite() && kappa > best.0 {
            best = (kappa, k);
        }
    }
    best.1
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corner_of_an_l_shape_is_found() {
        // ρ small and flat, then η drops sharply: corner at index 3.
        let pts = [
            (1.0, 1e4),
            (1.01, 1e3),
            (1.02, 1e2),
            (1.05, 1.0),
            (10.0, 0.9),
            (100.0, 0.8),
        ];
        assert_eq!(l_curve_corner(&pts), 3);
    }

    #[test]
    fn spatial_pairs_of_two_tets_sharing_a_face() {
        let tets = [[0, 1, 2, 3], [1, 2, 3, 4]];
        assert_eq!(spatial_pairs(&tets), vec![(0, 1)]);
        assert!((roughness(&[(0, 1)], &[1.0, 4.0]) - 3.0).abs() < 1e-15);
    }
}
