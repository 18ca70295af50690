//! The warp rotations R_e of many elements (eqs. 3.55–3.58), four at a time: the
//! Newton–Schulz iteration of `palpate_runtime::rotation::warp_rotation_polar` written as
//! structure-of-arrays lanes that compile to one AVX2 vector per operation.
//!
//! Why: one element at a time the iteration is a chain of dependent 3 × 3 products, and the
//! rotation pass was the largest single cost of a static diagnosis (a sixth of its profile's
//! samples). Four independent elements side by side fill the vector units instead: the pass
//! costs well under half as much.
//!
//! The lanes step together until every lane has converged, so a lane may take a step more than
//! it would alone: it is then closer to the fixed point, the same polar factor to rounding. A lane
//! the iteration does not suit — F not finite, det F ≤ 0, or F far from orthogonal
//! (‖XᵀX − I‖²_F ≥ ¼ at any step) — is left to the scalar routine, which handles it as it always
//! did (the SVD's reflection fix, or the scaled Newton iteration).

use nalgebra::Matrix3;
use palpate_runtime::rotation::{
    warp_rotation_polar, POLAR_CONVERGED as CONVERGED, POLAR_NEAR as NEAR,
};

/// Elements rotated side by side.
const LANES: usize = 4;

/// One value per lane.
type Lanes = [f64; LANES];

#[inline(always)]
fn lanes(value: impl Fn(usize) -> f64) -> Lanes {
    core::array::from_fn(value)
}

/// The polar rotations of four deformation gradients ([`warp_rotation_polar`]'s, to rounding).
fn polar_rotations_x4(f: &[Matrix3<f64>; LANES]) -> [Matrix3<f64>; LANES] {
    // x[3 i + j][lane] = X_ij (nalgebra stores column-major: (i, j) at 3 j + i).
    let mut x: [Lanes; 9] =
        core::array::from_fn(|k| lanes(|l| f[l].as_slice()[3 * (k % 3) + k / 3]));
    let det = lanes(|l| {
        x[0][l] * (x[4][l] * x[8][l] - x[5][l] * x[7][l])
            - x[1][l] * (x[3][l] * x[8][l] - x[5][l] * x[6][l])
            + x[2][l] * (x[3][l] * x[7][l] - x[4][l] * x[6][l])
    });
    // A NaN or infinite entry makes det NaN or infinite: both leave for the scalar routine.
    let mut scalar: [bool; LANES] = core::array::from_fn(|l| !(det[l] > 0.0 && det[l].is_finite()));
    let mut converged = false;
    for _ in 0..8 {
        let xtx = |a: usize, b: usize| {
            lanes(|l| x[a][l] * x[b][l] + x[3 + a][l] * x[3 + b][l] + x[6 + a][l] * x[6 + b][l])
        };
        let (s00, s11, s22) = (xtx(0, 0), xtx(1, 1), xtx(2, 2));
        let (s01, s02, s12) = (xtx(0, 1), xtx(0, 2), xtx(1, 2));
        let deviation = lanes(|l| {
            let (d0, d1, d2) = (s00[l] - 1.0, s11[l] - 1.0, s22[l] - 1.0);
            d0 * d0
                + d1 * d1
                + d2 * d2
                + 2.0 * (s01[l] * s01[l] + s02[l] * s02[l] + s12[l] * s12[l])
        });
        let mut worst = 0.0f64;
        for l in 0..LANES {
            // (A NaN deviation, an overflow, leaves too.)
            if deviation[l].partial_cmp(&NEAR) != Some(core::cmp::Ordering::Less) {
                scalar[l] = true;
            } else if !scalar[l] {
                worst = worst.max(deviation[l]);
            }
        }
        // X ← X (3I − XᵀX)/2.
        let m: [Lanes; 9] = [
            lanes(|l| 1.5 - 0.5 * s00[l]),
            lanes(|l| -0.5 * s01[l]),
            lanes(|l| -0.5 * s02[l]),
            lanes(|l| -0.5 * s01[l]),
            lanes(|l| 1.5 - 0.5 * s11[l]),
            lanes(|l| -0.5 * s12[l]),
            lanes(|l| -0.5 * s02[l]),
            lanes(|l| -0.5 * s12[l]),
            lanes(|l| 1.5 - 0.5 * s22[l]),
        ];
        x = core::array::from_fn(|k| {
            let (i, j) = (k / 3, k % 3);
            lanes(|l| {
                x[3 * i][l] * m[j][l]
                    + x[3 * i + 1][l] * m[3 + j][l]
                    + x[3 * i + 2][l] * m[6 + j][l]
            })
        });
        if worst < CONVERGED {
            converged = true;
            break;
        }
    }
    core::array::from_fn(|l| {
        if scalar[l] || !converged {
            warp_rotation_polar(&f[l])
        } else {
            Matrix3::from_fn(|i, j| x[3 * i + j][l])
        }
    })
}

/// The warp rotation of each deformation gradient in `f` (as [`warp_rotation_polar`], to
/// rounding), four at a time.
pub fn polar_rotations(f: &[Matrix3<f64>]) -> Vec<Matrix3<f64>> {
    let mut out = Vec::with_capacity(f.len());
    let mut batches = f.chunks_exact(LANES);
    for batch in &mut batches {
        let batch: &[Matrix3<f64>; LANES] = batch.try_into().expect("chunks of LANES");
        out.extend(polar_rotations_x4(batch));
    }
    out.extend(batches.remainder().iter().map(warp_rotation_polar));
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Vector3};

    /// F = R (I + E) with E's entries in ±`strain`, from a fixed sequence.
    fn gradients(count: usize, strain: f64, seed: u64) -> Vec<Matrix3<f64>> {
        let mut s = seed;
        let mut next = move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        };
        (0..count)
            .map(|_| {
                let axis = Vector3::new(next(), next(), next()) * 1.5;
                let r = Rotation3::from_scaled_axis(axis).into_inner();
                let e = Matrix3::from_fn(|_, _| next() * strain);
                r * (Matrix3::identity() + e)
            })
            .collect()
    }

    fn assert_agrees(f: &[Matrix3<f64>]) {
        let lanes = polar_rotations(f);
        assert_eq!(lanes.len(), f.len());
        for (k, (r, fk)) in lanes.iter().zip(f).enumerate() {
            let one = warp_rotation_polar(fk);
            let off = (r - one).amax();
            assert!(
                off <= 4e-15,
                "element {k}: lanes and the scalar routine differ by {off:e}\n{r}{one}"
            );
        }
    }

    #[test]
    fn lanes_give_the_scalar_routines_rotation_at_every_strain() {
        for (strain, seed) in [
            (0.0, 1),
            (1e-4, 2),
            (1e-2, 3),
            (0.05, 4),
            (0.2, 5),
            (0.6, 6),
        ] {
            // 4k + 3 elements: the remainder goes one at a time.
            assert_agrees(&gradients(4003, strain, seed));
        }
    }

    /// A batch whose lanes the iteration does not suit — inverted, flat, not finite, far from
    /// orthogonal — beside lanes it does: each gets the scalar routine's answer.
    #[test]
    fn lanes_the_iteration_does_not_suit_get_the_scalar_routine() {
        let good = gradients(8, 0.01, 7);
        let mut reflected = good[1];
        reflected.set_column(0, &(-good[1].column(0)));
        let flat = Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1e-12);
        let mut nan = good[2];
        nan[(1, 2)] = f64::NAN;
        let far = Matrix3::new(3.0, 0.5, 0.0, 0.0, 0.4, 0.1, 0.2, 0.0, 1.0);
        for bad in [reflected, flat, nan, far, Matrix3::zeros()] {
            for place in 0..LANES {
                let mut batch = good.clone();
                batch[place] = bad;
                assert_agrees(&batch);
            }
        }
    }
}
