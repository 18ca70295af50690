//! A scan's noise estimated from its own points, when the sensor's is not declared: the scatter
//! of each point's neighbourhood about its best-fitting plane. On a smooth surface sampled more
//! finely than it curves, that scatter is the noise along the normal; the median over the
//! points keeps edges, corners and flying pixels (whose neighbourhoods are not one plane) from
//! counting.

use nalgebra::{Matrix3, Vector3};
use std::collections::HashMap;

/// Neighbours in each plane fit.
const NEIGHBOURS: usize = 32;
/// Points whose neighbourhoods are fitted, at most (spread evenly through the scan).
const SAMPLES: usize = 4000;

/// The median, over up to 4,000 points spread through the scan, of the RMS distance of each
/// point's 32 nearest neighbours to their least-squares plane, corrected for the three degrees
/// of freedom the plane takes (× √(k/(k − 3))). `None` with fewer than 4 × 32 points.
pub fn local_scatter(points: &[Vector3<f64>]) -> Option<f64> {
    if points.len() < 4 * NEIGHBOURS {
        return None;
    }
    let mut lo = Vector3::repeat(f64::INFINITY);
    let mut hi = Vector3::repeat(f64::NEG_INFINITY);
    for p in points {
        lo = lo.inf(p);
        hi = hi.sup(p);
    }
    // Cells holding ~NEIGHBOURS points of a surface: the spacing of n points over an area
    // of about the box's largest face, times √k.
    let e = hi - lo;
    let mut sides = [e.x, e.y, e.z];
    sides.sort_by(f64::total_cmp);
    let area = (sides[1] * sides[2]).max(1e-18);
    let cell = (area / points.len() as f64 * NEIGHBOURS as f64)
        .sqrt()
        .max(1e-9);
    let key = |p: &Vector3<f64>| ((p - lo) / cell).map(|v| v.floor() as i64);
    let mut grid: HashMap<Vector3<i64>, Vec<usize>> = HashMap::new();
    for (i, p) in points.iter().enumerate() {
        grid.entry(key(p)).or_default().push(i);
    }
    let stride = (points.len() / SAMPLES).max(1);
    let mut scatter = Vec::new();
    let mut near: Vec<(f64, usize)> = Vec::new();
    for i in (0..points.len()).step_by(stride) {
        let p = points[i];
        let k = key(&p);
        near.clear();
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    if let Some(list) = grid.get(&(k + Vector3::new(dx, dy, dz))) {
                        near.extend(list.iter().map(|&j| ((points[j] - p).norm_squared(), j)));
                    }
                }
            }
        }
        if near.len() < NEIGHBOURS {
            continue;
        }
        near.select_nth_unstable_by(NEIGHBOURS - 1, |a, b| a.0.total_cmp(&b.0));
        let hood = &near[..NEIGHBOURS];
        let mean = hood.iter().map(|(_, j)| points[*j]).sum::<Vector3<f64>>() / NEIGHBOURS as f64;
        let mut cov = Matrix3::zeros();
        for (_, j) in hood {
            let d = points[*j] - mean;
            cov += d * d.transpose();
        }
        let smallest = cov.symmetric_eigenvalues().min().max(0.0);
        let k = NEIGHBOURS as f64;
        scatter.push((smallest / (k - 3.0)).sqrt());
    }
    if scatter.is_empty() {
        return None;
    }
    let mid = scatter.len() / 2;
    scatter.select_nth_unstable_by(mid, f64::total_cmp);
    Some(scatter[mid])
}

#[cfg(test)]
mod tests {
    use super::*;
    use palpate_fem::rng::SplitMix64;

    /// A 10 × 10 cm plane sampled at 1 mm, tilted, with noise of σ = 0.3 mm along its normal
    /// (drawn here): the estimate is within 6 % of the σ drawn. Measured 3.7 % low (a plane
    /// fitted to 32 noisy points tilts to take a little of their scatter); without the
    /// k/(k − 3) correction 8.3 % low, and with 16 neighbours 8.3 % low even with it.
    #[test]
    fn the_scatter_of_a_noisy_plane_is_its_noise() {
        let sigma = 3e-4;
        let n = Vector3::new(0.2, -0.3, 1.0).normalize();
        let u = n.cross(&Vector3::x()).normalize();
        let v = n.cross(&u);
        let mut rng = SplitMix64::new(4);
        let points: Vec<Vector3<f64>> = (0..100)
            .flat_map(|i| (0..100).map(move |j| (i, j)))
            .map(|(i, j)| u * (1e-3 * i as f64) + v * (1e-3 * j as f64))
            .map(|p| p + n * (sigma * rng.normal()))
            .collect();
        let s = local_scatter(&points).unwrap();
        assert!(
            (s / sigma - 1.0).abs() < 0.06,
            "estimated {s} for σ = {sigma}"
        );
        assert_eq!(local_scatter(&points[..10]), None);
    }
}
