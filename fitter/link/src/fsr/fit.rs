//! The fits: a power law `F = a · G^b` by least squares on `ln F = ln a + b ln G`
//! (multiplicative scatter, the FSR datasheets' log-log straight line), a monotone
//! piecewise-linear curve by isotonic regression (pool-adjacent-violators), and the usable range
//! from where the sensor still responds monotonically.

/// `(a, b)` of `F = a · G^b` from `(G, F)` pairs with `G, F > 0`; `None` with fewer than two
/// distinct conductances.
pub fn power_law(points: &[(f64, f64)]) -> Option<(f64, f64)> {
    let n = points.len() as f64;
    if points.len() < 2 {
        return None;
    }
    let (sx, sy) = points
        .iter()
        .fold((0.0, 0.0), |(sx, sy), &(g, f)| (sx + g.ln(), sy + f.ln()));
    let (mx, my) = (sx / n, sy / n);
    let (mut sxx, mut sxy) = (0.0, 0.0);
    for &(g, f) in points {
        let dx = g.ln() - mx;
        sxx += dx * dx;
        sxy += dx * (f.ln() - my);
    }
    if sxx <= 1e-12 {
        return None;
    }
    let b = sxy / sxx;
    Some(((my - b * mx).exp(), b))
}

/// Isotonic (non-decreasing) least-squares fit of `F` against `G` by pool-adjacent-violators.
/// Returns the pooled blocks as `(mean G, mean F, count)` with strictly increasing mean G.
pub fn isotonic(points: &[(f64, f64)]) -> Vec<(f64, f64, f64)> {
    let mut sorted = points.to_vec();
    sorted.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
    // Blocks as (sum G, sum F, count).
    let mut blocks: Vec<(f64, f64, f64)> = Vec::new();
    for (g, f) in sorted {
        blocks.push((g, f, 1.0));
        loop {
            let k = blocks.len();
            if k < 2 {
                break;
            }
            let (a, b) = (blocks[k - 2], blocks[k - 1]);
            // Pool when the force means violate monotonicity or the conductances tie (a curve
            // in G cannot hold two values at one G).
            if a.1 / a.2 >= b.1 / b.2 || (a.0 / a.2 - b.0 / b.2).abs() < 1e-12 {
                blocks.pop();
                let last = blocks.last_mut().expect("k >= 2");
                *last = (a.0 + b.0, a.1 + b.1, a.2 + b.2);
            } else {
                break;
            }
        }
    }
    blocks
        .into_iter()
        .map(|(sg, sf, n)| (sg / n, sf / n, n))
        .collect()
}

/// Picks at most `max` knots from isotonic blocks, always keeping the last; pooled means stay
/// monotone, so any subset does too.
pub fn knots(blocks: &[(f64, f64, f64)], max: usize) -> Vec<(f64, f64)> {
    if blocks.len() <= max {
        return blocks.iter().map(|&(g, f, _)| (g, f)).collect();
    }
    let last = blocks.len() - 1;
    (0..max)
        .map(|i| blocks[(i * last).div_ceil(max - 1).min(last)])
        .map(|(g, f, _)| (g, f))
        .collect()
}

/// Evaluates a piecewise-linear curve through `(0, 0)` and `knots` (last slope beyond).
pub fn eval_knots(knots: &[(f64, f64)], g: f64) -> f64 {
    let mut prev = (0.0, 0.0);
    for (i, &k) in knots.iter().enumerate() {
        if g <= k.0 || i + 1 == knots.len() {
            let dg = k.0 - prev.0;
            return if dg > 0.0 {
                prev.1 + (k.1 - prev.1) * (g - prev.0) / dg
            } else {
                k.1
            };
        }
        prev = k;
    }
    prev.1
}

/// The usable force range from repeated runs: group points by reference force level (zero
/// force excluded: it says nothing about the response), keep levels with at least
/// `min_per_level` points (a level seen in one run only is one noisy sample), take the median
/// conductance per level, and return the longest stretch of consecutive levels (≥ 2) over which
/// that median strictly increases — below it the sensor has not turned on reliably, above it
/// the response has flattened or turned over (FSR saturation). Saturated points enter with
/// `G = +∞`. Returns `(F_lo, F_hi)` in N.
pub fn usable_range(points: &[(f64, f64)], min_per_level: usize) -> Option<(f64, f64)> {
    let mut levels: Vec<(f64, Vec<f64>)> = Vec::new();
    let mut sorted = points.to_vec();
    sorted.sort_by(|a, b| a.1.total_cmp(&b.1));
    for (g, f) in sorted {
        match levels.last_mut() {
            Some((lf, gs)) if (*lf - f).abs() <= 1e-9 * f.max(1.0) => gs.push(g),
            _ => levels.push((f, vec![g])),
        }
    }
    let med: Vec<(f64, f64)> = levels
        .into_iter()
        .filter(|(f, gs)| *f > 0.0 && gs.len() >= min_per_level)
        .map(|(f, mut gs)| {
            gs.sort_by(f64::total_cmp);
            let n = gs.len();
            (
                f,
                if n % 2 == 1 {
                    gs[n / 2]
                } else {
                    0.5 * (gs[n / 2 - 1] + gs[n / 2])
                },
            )
        })
        .collect();
    let (mut best, mut start) = ((0, 0), 0);
    for i in 1..=med.len() {
        if i == med.len() || med[i].1 <= med[i - 1].1 {
            if i - start > best.1 - best.0 {
                best = (start, i);
            }
            start = i;
        }
    }
    (best.1 - best.0 >= 2).then(|| (med[best.0].0, med[best.1 - 1].0))
}

/// Median of a slice (copied).
pub fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn power_law_recovers_exact_parameters() {
        let pts: Vec<(f64, f64)> = [10.0, 50.0, 200.0, 900.0]
            .iter()
            .map(|&g: &f64| (g, 0.02 * g.powf(1.3)))
            .collect();
        let (a, b) = power_law(&pts).unwrap();
        assert!(
            (a / 0.02 - 1.0).abs() < 1e-10 && (b - 1.3).abs() < 1e-12,
            "{a} {b}"
        );
    }

    #[test]
    fn isotonic_matches_a_hand_worked_example() {
        // F at G = 1,2,3,4: 1, 3, 2, 4 → PAV pools (3, 2) into 2.5 at G = 2.5.
        let b = isotonic(&[(1.0, 1.0), (2.0, 3.0), (3.0, 2.0), (4.0, 4.0)]);
        assert_eq!(b, vec![(1.0, 1.0, 1.0), (2.5, 2.5, 2.0), (4.0, 4.0, 1.0)]);
        assert_eq!(eval_knots(&[(2.0, 1.0), (4.0, 5.0)], 1.0), 0.5);
        assert_eq!(eval_knots(&[(2.0, 1.0), (4.0, 5.0)], 5.0), 7.0);
        let k = knots(
            &(0..30)
                .map(|i| (i as f64, i as f64, 1.0))
                .collect::<Vec<_>>(),
            12,
        );
        assert_eq!((k.len(), k[11]), (12, (29.0, 29.0)));
    }

    #[test]
    fn usable_range_is_the_longest_increasing_stretch_of_level_medians() {
        // Levels 1..6 N; medians rise 2..5 N, then fall at 6 N; 1 N is above 2 N (noise).
        let pts = [
            (9.0, 1.0),
            (3.0, 2.0),
            (4.0, 2.0),
            (5.0, 3.0),
            (7.0, 4.0),
            (8.0, 5.0),
            (6.0, 6.0),
        ];
        assert_eq!(usable_range(&pts, 1), Some((2.0, 5.0)));
        // Requiring two points per level leaves only 2 N: no stretch.
        assert_eq!(usable_range(&pts, 2), None);
    }
}
