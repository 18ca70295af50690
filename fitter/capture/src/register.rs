//! Horn's closed-form absolute orientation (B. K. P. Horn, "Closed-form solution of absolute
//! orientation using unit quaternions", JOSA A 4(4), 1987): the rotation R and translation t that
//! minimise Σᵢ ‖R aᵢ + t − bᵢ‖² over labelled point pairs — here the markers in the capture frame
//! (aᵢ) and their places in the mesh frame (bᵢ), the registration of thesis §4.2.
//!
//! R is the rotation of the unit quaternion that is the eigenvector of the largest eigenvalue of
//! Horn's symmetric 4 × 4 matrix N built from the cross-covariance of the centred sets (his
//! eq. 4.23); t = b̄ − R ā. The SVD (Kabsch) solution is the same minimiser.

use nalgebra::{Matrix3, Matrix4, Quaternion, SymmetricEigen, UnitQuaternion, Vector3};

/// Why a registration cannot be computed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum RegistrationError {
    /// Fewer than three point pairs.
    #[error("registration needs at least 3 markers, found {0}")]
    TooFew(usize),
    /// The two lists differ in length.
    #[error("registration: {from} capture points but {to} model points")]
    Mismatch {
        /// Capture-frame points.
        from: usize,
        /// Model-frame points.
        to: usize,
    },
    /// The points lie on a line (or coincide): the rotation about that line is undetermined.
    #[error(
        "registration: the {which} points are collinear (spread across the line {spread:.3e} m \
         against {length:.3e} m along it): the rotation about that line is not determined; use \
         at least 3 markers that are not on one line"
    )]
    Collinear {
        /// "capture" or "model".
        which: &'static str,
        /// RMS distance of the points from their best-fit line (m).
        spread: f64,
        /// RMS extent along the line (m).
        length: f64,
    },
    /// A coordinate is not finite.
    #[error("registration: point {0} is not finite")]
    NonFinite(usize),
}

/// A rigid transform x ↦ R x + t with the fit's residuals.
#[derive(Debug, Clone, PartialEq)]
pub struct RigidTransform {
    /// Rotation.
    pub rotation: Matrix3<f64>,
    /// Translation (m).
    pub translation: Vector3<f64>,
    /// ‖R aᵢ + t − bᵢ‖ of every pair (m), in input order.
    pub residuals: Vec<f64>,
}

impl RigidTransform {
    /// Applies the transform to a point.
    pub fn apply(&self, p: [f64; 3]) -> [f64; 3] {
        let q = self.rotation * Vector3::from(p) + self.translation;
        [q.x, q.y, q.z]
    }
    /// RMS of the residuals (m).
    pub fn rms(&self) -> f64 {
        (self.residuals.iter().map(|r| r * r).sum::<f64>() / self.residuals.len().max(1) as f64)
            .sqrt()
    }
}

/// Collinearity is judged relative to the set's own size: the second principal spread below
/// this fraction of the first.
const COLLINEAR_RATIO: f64 = 1e-6;

fn centred(
    points: &[[f64; 3]],
    which: &'static str,
) -> Result<(Vector3<f64>, Vec<Vector3<f64>>), RegistrationError> {
    let n = points.len() as f64;
    let mut c = Vector3::zeros();
    for (i, p) in points.iter().enumerate() {
        if !p.iter().all(|v| v.is_finite()) {
            return Err(RegistrationError::NonFinite(i));
        }
        c += Vector3::from(*p) / n;
    }
    let d: Vec<Vector3<f64>> = points.iter().map(|p| Vector3::from(*p) - c).collect();
    let cov = d
        .iter()
        .fold(Matrix3::zeros(), |m, v| m + v * v.transpose())
        / n;
    let mut ev: Vec<f64> = SymmetricEigen::new(cov)
        .eigenvalues
        .iter()
        .copied()
        .collect();
    ev.sort_by(|a, b| b.total_cmp(a));
    let (first, second) = (ev[0].max(0.0).sqrt(), ev[1].max(0.0).sqrt());
    if second <= COLLINEAR_RATIO * first || first == 0.0 {
        return Err(RegistrationError::Collinear {
            which,
            spread: second,
            length: first,
        });
    }
    Ok((c, d))
}

/// Horn's closed form: the rotation maximising Σ q'ᵢ · R p'ᵢ for the cross-covariance
/// S = Σ p'ᵢ q'ᵢᵀ of centred pairs — the eigenvector of the largest eigenvalue of his symmetric
/// 4 × 4 matrix N(S), read as a unit quaternion.
fn horn_rotation(s: &Matrix3<f64>) -> Matrix3<f64> {
    let (sxx, sxy, sxz) = (s[(0, 0)], s[(0, 1)], s[(0, 2)]);
    let (syx, syy, syz) = (s[(1, 0)], s[(1, 1)], s[(1, 2)]);
    let (szx, szy, szz) = (s[(2, 0)], s[(2, 1)], s[(2, 2)]);
    #[rustfmt::skip]
    let n = Matrix4::new(
        sxx + syy + szz, syz - szy,        szx - sxz,        sxy - syx,
        syz - szy,       sxx - syy - szz,  sxy + syx,        szx + sxz,
        szx - sxz,       sxy + syx,        -sxx + syy - szz, syz + szy,
        sxy - syx,       szx + sxz,        syz + szy,        -sxx - syy + szz,
    );
    let eig = SymmetricEigen::new(n);
    let at = (0..4)
        .max_by(|&a, &b| eig.eigenvalues[a].total_cmp(&eig.eigenvalues[b]))
        .unwrap_or(0);
    let v = eig.eigenvectors.column(at);
    UnitQuaternion::from_quaternion(Quaternion::new(v[0], v[1], v[2], v[3]))
        .to_rotation_matrix()
        .into_inner()
}

/// The rigid transform taking `from` (capture frame) onto `to` (model frame), pair by pair.
pub fn absolute_orientation(
    from: &[[f64; 3]],
    to: &[[f64; 3]],
) -> Result<RigidTransform, RegistrationError> {
    if from.len() != to.len() {
        return Err(RegistrationError::Mismatch {
            from: from.len(),
            to: to.len(),
        });
    }
    if from.len() < 3 {
        return Err(RegistrationError::TooFew(from.len()));
    }
    let (ca, a) = centred(from, "capture")?;
    let (cb, b) = centred(to, "model")?;
    // Cross-covariance S_kl = Σ a'_k b'_l (Horn's M).
    let s = a
        .iter()
        .zip(&b)
        .fold(Matrix3::zeros(), |m, (p, q)| m + p * q.transpose());
    let rotation = horn_rotation(&s);
    let translation = cb - rotation * ca;
    let residuals = from
        .iter()
        .zip(to)
        .map(|(p, q)| (rotation * Vector3::from(*p) + translation - Vector3::from(*q)).norm())
        .collect();
    Ok(RigidTransform {
        rotation,
        translation,
        residuals,
    })
}

/// Horn's absolute orientation with a weight per pair: the rigid transform minimising
/// Σ w_i ‖R p_i + t − q_i‖² (weighted centroids and cross-covariance; the same quaternion
/// eigenproblem). For per-measurement re-registration inside a fit, where markers the load moves
/// are down-weighted; `None` when the weights vanish or a value is not finite (no transform is
/// better than a made-up one).
pub fn weighted_orientation(
    from: &[[f64; 3]],
    to: &[[f64; 3]],
    w: &[f64],
) -> Option<(Matrix3<f64>, Vector3<f64>)> {
    if from.len() != to.len() || from.len() != w.len() || from.len() < 3 {
        return None;
    }
    let total: f64 = w.iter().sum();
    if !(total > 0.0 && total.is_finite()) {
        return None;
    }
    let mean = |pts: &[[f64; 3]]| {
        pts.iter().zip(w).fold(Vector3::zeros(), |c, (p, wi)| {
            c + Vector3::from(*p) * (*wi / total)
        })
    };
    let (ca, cb) = (mean(from), mean(to));
    let s = from
        .iter()
        .zip(to)
        .zip(w)
        .fold(Matrix3::zeros(), |m, ((p, q), wi)| {
            m + (Vector3::from(*p) - ca) * (Vector3::from(*q) - cb).transpose() * *wi
        });
    if !s.iter().all(|v| v.is_finite()) {
        return None;
    }
    let rotation = horn_rotation(&s);
    Some((rotation, cb - rotation * ca))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    fn cloud() -> Vec<[f64; 3]> {
        vec![
            [0.0, 0.015, 0.036],
            [0.0, -0.006, 0.024],
            [0.0, 0.036, 0.006],
            [-0.094, -0.01, -0.001],
            [-0.094, 0.04, 0.0275],
            [-0.094, 0.04, 0.0],
        ]
    }

    /// A known transform is recovered to 1e-9 from noise-free points, whatever the rotation.
    #[test]
    fn recovers_a_known_transform_exactly() {
        for (axis, angle) in [
            ([0.3, -0.5, 0.8], 2.1),
            ([1.0, 0.0, 0.0], std::f64::consts::PI - 1e-3),
            ([0.0, 0.0, 1.0], 1e-4),
        ] {
            let r = Rotation3::from_axis_angle(
                &nalgebra::Unit::new_normalize(Vector3::from(axis)),
                angle,
            );
            let t = Vector3::new(0.4, -1.2, 0.75);
            let model = cloud();
            let lab: Vec<[f64; 3]> = model
                .iter()
                .map(|p| {
                    let q = r.inverse() * (Vector3::from(*p) - t);
                    [q.x, q.y, q.z]
                })
                .collect();
            let fit = absolute_orientation(&lab, &model).unwrap();
            assert!(
                (fit.rotation - r.matrix()).abs().max() < 1e-9,
                "{}",
                fit.rotation
            );
            assert!((fit.translation - t).abs().max() < 1e-9);
            assert!(fit.rms() < 1e-9);
        }
    }

    /// With 1 mm noise on the capture the residual RMS is of the noise's size and the
    /// transform moves a point 10 cm away by no more than a few millimetres.
    #[test]
    fn degrades_gracefully_with_noise() {
        let r = Rotation3::from_euler_angles(0.2, -0.4, 1.1);
        let t = Vector3::new(0.1, 0.2, 0.3);
        let model = cloud();
        let mut state = 7u64;
        let mut noise = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 2e-3
        };
        let lab: Vec<[f64; 3]> = model
            .iter()
            .map(|p| {
                let q = r.inverse() * (Vector3::from(*p) - t);
                [q.x + noise(), q.y + noise(), q.z + noise()]
            })
            .collect();
        let fit = absolute_orientation(&lab, &model).unwrap();
        assert!(fit.rms() > 1e-4 && fit.rms() < 2e-3, "rms {}", fit.rms());
        let probe = [-0.05, 0.015, 0.015];
        let truth = r * (r.inverse() * (Vector3::from(probe) - t)) + t;
        let q = r.inverse() * (Vector3::from(probe) - t);
        let mapped = fit.apply([q.x, q.y, q.z]);
        assert!((Vector3::from(mapped) - truth).norm() < 3e-3);
    }

    /// Fewer than three markers, or markers on a line, are clear errors.
    #[test]
    fn too_few_or_collinear_markers_are_errors() {
        let e = absolute_orientation(&cloud()[..2], &cloud()[..2]).unwrap_err();
        assert_eq!(e, RegistrationError::TooFew(2));
        assert!(e.to_string().contains("at least 3"));
        let line: Vec<[f64; 3]> = (0..4)
            .map(|k| [0.01 * k as f64, 0.02 * k as f64, 0.0])
            .collect();
        let e = absolute_orientation(&line, &line).unwrap_err();
        assert!(matches!(e, RegistrationError::Collinear { .. }), "{e}");
        assert!(e.to_string().contains("not on one line"), "{e}");
        let e = absolute_orientation(&cloud(), &cloud()[..5]).unwrap_err();
        assert!(matches!(e, RegistrationError::Mismatch { from: 6, to: 5 }));
    }

    /// With equal weights the weighted solution is Horn's; a weight of zero ignores a pair,
    /// however far off it is.
    #[test]
    fn weighted_orientation_agrees_and_ignores_zero_weights() {
        let r = Rotation3::from_axis_angle(
            &nalgebra::Unit::new_normalize(Vector3::new(0.2, 1.0, -0.4)),
            0.3,
        );
        let t = Vector3::new(0.01, -0.02, 0.005);
        let a = cloud();
        let mut b: Vec<[f64; 3]> = a
            .iter()
            .map(|p| {
                let q = r * Vector3::from(*p) + t;
                [q.x, q.y, q.z]
            })
            .collect();
        let (rw, tw) = weighted_orientation(&a, &b, &[1.0; 6]).unwrap();
        assert!((rw - r.matrix()).norm() < 1e-9 && (tw - t).norm() < 1e-9);
        b[0][2] += 1.0;
        let mut w = [1.0; 6];
        w[0] = 0.0;
        let (rw, tw) = weighted_orientation(&a, &b, &w).unwrap();
        assert!((rw - r.matrix()).norm() < 1e-9 && (tw - t).norm() < 1e-9);
        assert!(weighted_orientation(&a, &b, &[0.0; 6]).is_none());
    }
}
