//! Element rotations for stiffness warping (seed 000 §3.3.3, eqs. 3.55–3.58).
//!
//! Eq. 3.57 gives the affine map X_e X_{0,e}⁻¹ whose linear block Y_e is the deformation gradient
//! F of the element; eq. 3.58 takes the rotation from its SVD. Taken literally that can return a
//! *reflection* (det = −1) when the element is inverted or flat, and a reflection in
//! K' = Σ R_e K_e R_eᵀ turns an inverted element's restoring force inside out. Both functions here
//! always return a proper rotation: the maximiser of tr(Rᵀ F) over SO(3), i.e.
//! R = U diag(1, 1, det(U Vᵀ)) Vᵀ (the smallest singular direction is flipped, as in invertible FEM).

use nalgebra::{Matrix3, RealField, UnitQuaternion, Vector3};

/// Proper rotation of F by SVD with the reflection fixed (eq. 3.58 made safe). Reference version;
/// returns the identity for non-finite input.
pub fn warp_rotation_svd<T: RealField + Copy>(f: &Matrix3<T>) -> Matrix3<T> {
    if !f.iter().all(|v| v.is_finite()) {
        return Matrix3::identity();
    }
    let svd = f.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return Matrix3::identity();
    };
    // nalgebra sorts singular values in decreasing order: the last one is the smallest.
    let mut r = u * v_t;
    if r.determinant() < T::zero() {
        let mut u2 = u;
        let c = -u2.column(2).into_owned();
        u2.set_column(2, &c);
        r = u2 * v_t;
    }
    r
}

/// Iterative rotation extraction (Müller, Bender, Chentanez, Macklin 2016, "A robust method to
/// extract the rotational part of deformations"), warm-started from `q`, which is updated.
///
/// Each iteration rotates q towards the maximiser of tr(Rᵀ F); the result is always a unit
/// quaternion, so a proper rotation even for inverted or flat elements. Warm-started from the
/// previous tick it converges in one or two iterations, which is why the haptic loop uses it.
pub fn warp_rotation_iterative<T: RealField + Copy>(
    f: &Matrix3<T>,
    q: &mut UnitQuaternion<T>,
    max_iterations: usize,
) -> Matrix3<T> {
    let eps = T::from_f64(1e-9).unwrap();
    if !f.iter().all(|v| v.is_finite()) {
        return q.to_rotation_matrix().into_inner();
    }
    for _ in 0..max_iterations {
        let r = q.to_rotation_matrix().into_inner();
        let mut omega = Vector3::<T>::zeros();
        let mut dot = T::zero();
        for c in 0..3 {
            let rc = r.column(c);
            let fc = f.column(c);
            omega += rc.cross(&fc);
            dot += rc.dot(&fc);
        }
        let omega = omega / (dot.abs() + eps);
        let w = omega.norm();
        if w < eps {
            break;
        }
        let step = UnitQuaternion::from_scaled_axis(omega);
        *q = UnitQuaternion::new_normalize((step * *q).into_inner());
    }
    q.to_rotation_matrix().into_inner()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Rotation3;

    fn is_proper_rotation(r: &Matrix3<f64>) -> bool {
        (r.transpose() * r - Matrix3::identity()).norm() < 1e-8
            && (r.determinant() - 1.0).abs() < 1e-8
    }

    #[test]
    fn svd_rotation_of_rotated_stretch_is_the_rotation() {
        let rot = Rotation3::from_euler_angles(0.3, -1.1, 2.0).into_inner();
        let s = Matrix3::new(1.2, 0.1, 0.0, 0.1, 0.9, 0.05, 0.0, 0.05, 1.05);
        let r = warp_rotation_svd(&(rot * s));
        assert!((r - rot).norm() < 1e-10);
    }

    #[test]
    fn inverted_element_gives_proper_rotation_not_reflection() {
        let rot = Rotation3::from_euler_angles(0.4, 0.2, -0.7).into_inner();
        // A flip of z: det F < 0. nalgebra's polar() would return a reflection here.
        let f = rot * Matrix3::from_diagonal(&Vector3::new(1.0, 0.8, -0.3));
        assert!(f.determinant() < 0.0);
        let r = warp_rotation_svd(&f);
        assert!(is_proper_rotation(&r), "svd: {r}");
        // Expected: flip the smallest singular direction (z, 0.3) → R = rot.
        assert!((r - rot).norm() < 1e-10);
        let mut q = UnitQuaternion::identity();
        let ri = warp_rotation_iterative(&f, &mut q, 100);
        assert!(is_proper_rotation(&ri), "iterative: {ri}");
        assert!((ri - rot).norm() < 1e-6, "iterative {ri} vs {rot}");
    }

    #[test]
    fn flat_element_gives_proper_rotation() {
        let f = Matrix3::from_diagonal(&Vector3::new(1.0, 1.0, 0.0));
        assert!(is_proper_rotation(&warp_rotation_svd(&f)));
        let mut q = UnitQuaternion::identity();
        assert!(is_proper_rotation(&warp_rotation_iterative(&f, &mut q, 20)));
    }

    #[test]
    fn iterative_agrees_with_svd_for_random_deformations() {
        let mut seed = 12345u64;
        let mut rnd = || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((seed >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        };
        for _ in 0..200 {
            let rot =
                Rotation3::from_euler_angles(3.0 * rnd(), 3.0 * rnd(), 3.0 * rnd()).into_inner();
            let mut s = Matrix3::identity();
            for v in s.iter_mut() {
                *v += 0.3 * rnd();
            }
            let f = rot * s;
            if f.determinant() <= 0.05 {
                continue;
            }
            let r_svd = warp_rotation_svd(&f);
            let mut q = UnitQuaternion::identity();
            let r_it = warp_rotation_iterative(&f, &mut q, 200);
            assert!((r_svd - r_it).norm() < 1e-6, "{r_svd} vs {r_it}");
        }
    }
}
