//! Element rotations for stiffness warping (seed 000 §3.3.3, eqs. 3.55–3.58).
//!
//! Eq. 3.57 gives the affine map X_e X_{0,e}⁻¹ whose linear block Y_e is the deformation gradient
//! F of the element; eq. 3.58 takes the rotation from its SVD. Taken literally that can return a
//! *reflection* (det = −1) when the element is inverted or flat, and a reflection in
//! K' = Σ R_e K_e R_eᵀ turns an inverted element's restoring force inside out. Both functions here
//! always return a proper rotation: the maximiser of tr(Rᵀ F) over SO(3), i.e.
//! R = U diag(1, 1, det(U Vᵀ)) Vᵀ (the smallest singular direction is flipped, as in invertible FEM).

use crate::kernel::LANES;
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

/// [`warp_rotation_polar`]'s switch: at a squared deviation ‖XᵀX − I‖²_F below it the
/// inverse-free Newton–Schulz iteration is used (strains up to ≈ 20 %), above it the scaled Newton
/// iteration.
pub const POLAR_NEAR: f64 = 0.25;

/// [`warp_rotation_polar`]'s convergence test: a squared deviation below it is followed by one last
/// Newton–Schulz step, which leaves rounding.
pub const POLAR_CONVERGED: f64 = 1e-18;

/// [`warp_rotation_svd`] by iterations for the orthogonal polar factor (N. J. Higham, "Computing
/// the polar decomposition — with applications", SIAM J. Sci. Stat. Comput. 7, 1986): the
/// inverse-free Newton–Schulz iteration X ← X(3I − XᵀX)/2 while F is near orthogonal, else the
/// scaled Newton iteration X ← ½(γX + γ⁻¹X⁻ᵀ), γ = (‖X⁻¹‖_F / ‖X‖_F)^½. For det F > 0 the polar
/// factor is U Vᵀ, the same rotation the SVD gives, reached to rounding — many times cheaper
/// than a general SVD, which is what the offline fitter's rotation updates spent a third of a
/// diagnosis on. F with det ≤ 0 (inverted or flat
/// elements: the SVD's reflection fix is needed), non-finite F, or an iteration that has not
/// converged fall back to [`warp_rotation_svd`].
pub fn warp_rotation_polar<T: RealField + Copy>(f: &Matrix3<T>) -> Matrix3<T> {
    if !f.iter().all(|v| v.is_finite()) {
        return Matrix3::identity();
    }
    let det = f.determinant();
    // det ≤ 0: inverted or flat; the SVD's reflection fix is needed (the polar factor would be a
    // reflection).
    if det <= T::zero() {
        return warp_rotation_svd(f);
    }
    let half = T::from_f64(0.5).unwrap();
    let one_and_half = T::from_f64(1.5).unwrap();
    // Near an orthogonal matrix (‖XᵀX − I‖_F < ½: strains up to ≈ 20 %, the common case) the
    // inverse-free Newton–Schulz step X ← X (3I − XᵀX)/2 converges quadratically to the same
    // polar factor with only products; a deviation below 1e-9 is followed by one last step,
    // which leaves an error of order 1e-18, i.e. rounding. The deviation is compared squared: the
    // squared Frobenius norm of the symmetric XᵀX − I (a sum, six entries): its largest entry
    // by nalgebra's `amax` was a chain of dependent compares that took half of this function's
    // time, and this function a quarter of a static diagnosis.
    let near = T::from_f64(POLAR_NEAR).unwrap();
    let done = T::from_f64(POLAR_CONVERGED).unwrap();
    let mut x = *f;
    for _ in 0..8 {
        let xtx = x.transpose() * x;
        let one = T::one();
        let (d0, d1, d2) = (xtx[(0, 0)] - one, xtx[(1, 1)] - one, xtx[(2, 2)] - one);
        let (o01, o02, o12) = (xtx[(0, 1)], xtx[(0, 2)], xtx[(1, 2)]);
        let two = one + one;
        let deviation = d0 * d0 + d1 * d1 + d2 * d2 + two * (o01 * o01 + o02 * o02 + o12 * o12);
        // (A NaN deviation — overflow — also leaves for the guarded path.)
        if deviation.partial_cmp(&near) != Some(core::cmp::Ordering::Less) {
            break;
        }
        x *= Matrix3::identity() * one_and_half - xtx * half;
        if deviation < done {
            return x;
        }
    }
    // Nearly flat elements (det tiny against ‖F‖³) have an ill-conditioned polar factor; the SVD
    // handles them.
    let scale = f.norm();
    if det <= T::from_f64(1e-6).unwrap() * scale * scale * scale {
        return warp_rotation_svd(f);
    }
    // Far from orthogonal: Higham's scaled Newton from F itself. Quadratic convergence: once an
    // update is below 1e-8 the next one leaves an error of order 1e-16, rounding; waiting for an
    // update below rounding instead can stall at it.
    let tolerance = T::from_f64(1e-8).unwrap();
    let mut x = *f;
    let mut converged = false;
    for iteration in 0..12 {
        let Some(inv) = x.try_inverse() else {
            return warp_rotation_svd(f);
        };
        let inv_t = inv.transpose();
        // Scaling only while far from orthogonal; near convergence γ → 1 and the unscaled step
        // converges quadratically without the scaling's rounding.
        let gamma = if iteration < 3 {
            (inv.norm() / x.norm()).sqrt()
        } else {
            T::one()
        };
        let next = (x * gamma + inv_t / gamma) * half;
        let change = (next - x).norm();
        x = next;
        if converged {
            return x;
        }
        converged = change <= tolerance;
    }
    warp_rotation_svd(f)
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

/// The runtime's f32 fast path of [`warp_rotation_iterative`]: plain arrays, and each step's
/// rotation exp(ω) replaced by the normalised first-order quaternion (1, ω/2), which needs no
/// trigonometry. The fixed point is the same (ω = 0 there), every iterate is a unit quaternion
/// (a proper rotation), and warm-started from the previous tick one step suffices. At most
/// `iterations` steps; a step that turns the rotation by less than `tolerance` (rad) is the last
/// (the iteration has converged that far, and the next step would be smaller still: 0 runs every
/// step). `q` is (w, x, y, z); `r` receives R row-major.
#[inline(always)]
pub fn warp_rotation_fast(
    f: &[f32; 9],
    q: &mut [f32; 4],
    iterations: usize,
    tolerance: f32,
    r: &mut [f32; 9],
) {
    quat_to_matrix(q, r);
    if !f.iter().all(|v| v.is_finite()) {
        return;
    }
    let last = converged_step2(tolerance);
    for _ in 0..iterations {
        let h = rotation_step(|k| r[k], |k| f[k]);
        let h2 = h[0] * h[0] + h[1] * h[1] + h[2] * h[2];
        if h2 < 1e-14 {
            break;
        }
        // q ← normalise((1, h) ⊗ q)
        let nq = quat_step(*q, h);
        let n = libm::sqrtf(nq[0] * nq[0] + nq[1] * nq[1] + nq[2] * nq[2] + nq[3] * nq[3]);
        if n.is_nan() || n <= 0.0 || !n.is_finite() {
            break;
        }
        for k in 0..4 {
            q[k] = nq[k] / n;
        }
        quat_to_matrix(q, r);
        if h2 < last {
            break;
        }
    }
}

/// |h|² of a step (1, h) that turns by less than `tolerance` rad (2|h|): the iteration's last.
#[inline(always)]
fn converged_step2(tolerance: f32) -> f32 {
    let t = 0.5 * tolerance;
    t * t
}

/// One step of the rotation update, shared by [`warp_rotation_fast`] and its lane version:
/// h = ω / 2 with ω = Σ_c r_c × f_c / |Σ_c r_c · f_c| (columns c of R and F, entry k of each
/// row-major matrix read through `r(k)`, `f(k)`).
#[inline(always)]
fn rotation_step(r: impl Fn(usize) -> f32, f: impl Fn(usize) -> f32) -> [f32; 3] {
    let mut om = [0.0f32; 3];
    let mut dot = 0.0f32;
    for c in 0..3 {
        let rc = [r(c), r(3 + c), r(6 + c)];
        let fc = [f(c), f(3 + c), f(6 + c)];
        om[0] += rc[1] * fc[2] - rc[2] * fc[1];
        om[1] += rc[2] * fc[0] - rc[0] * fc[2];
        om[2] += rc[0] * fc[1] - rc[1] * fc[0];
        dot += rc[0] * fc[0] + rc[1] * fc[1] + rc[2] * fc[2];
    }
    let inv = 1.0 / (dot.abs() + 1e-9);
    [0.5 * om[0] * inv, 0.5 * om[1] * inv, 0.5 * om[2] * inv]
}

/// (1, h) ⊗ q, not normalised (the callers normalise, each with its own guards).
#[inline(always)]
fn quat_step(q: [f32; 4], h: [f32; 3]) -> [f32; 4] {
    let [w, x, y, z] = q;
    [
        w - h[0] * x - h[1] * y - h[2] * z,
        x + h[0] * w + h[1] * z - h[2] * y,
        y - h[0] * z + h[1] * w + h[2] * x,
        z + h[0] * y - h[1] * x + h[2] * w,
    ]
}

/// [`warp_rotation_fast`] for [`LANES`] elements at once (structure of arrays: `f[k][l]` is entry
/// k of lane l's F), so the update compiles to SIMD. Lane by lane it takes the same steps: a lane
/// whose F is not finite keeps its rotation, a lane whose increment is below the scalar
/// version's stopping threshold is left unchanged (the scalar loop stops there; later iterations
/// would find the same increment again), a lane whose step turned by less than `tolerance` takes
/// no more, and the loop ends when no lane is left. Returns an upper bound of the angle (rad) by
/// which any lane's rotation moved: each step (1, h) turns by 2 atan|h| ≤ 2 |h|₁.
#[inline(always)]
#[allow(clippy::needless_range_loop)]
pub fn warp_rotation_fast_lanes(
    f: &[[f32; LANES]; 9],
    q: &mut [[f32; LANES]; 4],
    iterations: usize,
    tolerance: f32,
    r: &mut [[f32; LANES]; 9],
) -> f32 {
    let mut moved = [0.0f32; LANES];
    let mut finite = [true; LANES];
    for k in 0..9 {
        for l in 0..LANES {
            finite[l] &= f[k][l].is_finite();
        }
    }
    quat_to_matrix_lanes(q, r);
    let last = converged_step2(tolerance);
    // Lanes still iterating: a lane stops where the scalar loop does, and the block when every
    // lane has (a haptic tick's small motions: one step, not `iterations`).
    let mut active = finite;
    for _ in 0..iterations {
        let mut nq = [[0.0f32; LANES]; 4];
        let mut n2 = [0.0f32; LANES];
        let mut take = [false; LANES];
        let mut more = false;
        for l in 0..LANES {
            let h = rotation_step(|k| r[k][l], |k| f[k][l]);
            let ql = quat_step([q[0][l], q[1][l], q[2][l], q[3][l]], h);
            for k in 0..4 {
                nq[k][l] = ql[k];
            }
            n2[l] = nq[0][l] * nq[0][l]
                + nq[1][l] * nq[1][l]
                + nq[2][l] * nq[2][l]
                + nq[3][l] * nq[3][l];
            let h2 = h[0] * h[0] + h[1] * h[1] + h[2] * h[2];
            take[l] = active[l] && h2 >= 1e-14;
            active[l] = take[l] && h2 >= last;
            more |= active[l];
            let angle = 2.0 * (h[0].abs() + h[1].abs() + h[2].abs());
            moved[l] += if take[l] { angle } else { 0.0 };
        }
        let inv = inv_sqrt_lanes(&n2);
        for l in 0..LANES {
            let ok = take[l] && n2[l] > 0.0 && n2[l].is_finite() && inv[l].is_finite();
            let s = if ok { inv[l] } else { 0.0 };
            for k in 0..4 {
                q[k][l] = if ok { nq[k][l] * s } else { q[k][l] };
            }
        }
        quat_to_matrix_lanes(q, r);
        if !more {
            break;
        }
    }
    moved.iter().fold(0.0f32, |m, &a| if a > m { a } else { m })
}

/// 1/√x lane by lane for normal positive x (a unit quaternion's step has |q|² = 1 + |h|² ≥ 1),
/// without a library call: the float's exponent halved through its bits (the classic first
/// guess, within 3.5 %), then three Newton steps y ← y (1.5 − 0.5 x y²), each squaring the
/// relative error — f32 round-off after three. Plain arithmetic, so the lanes compile to SIMD:
/// `libm::sqrtf` per lane had compiled to eight scalar square roots whose samples were three
/// quarters of the residual pass's (`perf annotate`, `bench runtime --tets 5000`).
#[inline(always)]
fn inv_sqrt_lanes(x: &[f32; LANES]) -> [f32; LANES] {
    let mut y = [0.0f32; LANES];
    for l in 0..LANES {
        y[l] = f32::from_bits(0x5f37_59df_u32.wrapping_sub(x[l].to_bits() >> 1));
    }
    for _ in 0..3 {
        for l in 0..LANES {
            y[l] *= 1.5 - 0.5 * x[l] * y[l] * y[l];
        }
    }
    y
}

/// [`quat_to_matrix`] lane by lane.
#[inline(always)]
pub fn quat_to_matrix_lanes(q: &[[f32; LANES]; 4], r: &mut [[f32; LANES]; 9]) {
    for l in 0..LANES {
        let (w, x, y, z) = (q[0][l], q[1][l], q[2][l], q[3][l]);
        r[0][l] = 1.0 - 2.0 * (y * y + z * z);
        r[1][l] = 2.0 * (x * y - w * z);
        r[2][l] = 2.0 * (x * z + w * y);
        r[3][l] = 2.0 * (x * y + w * z);
        r[4][l] = 1.0 - 2.0 * (x * x + z * z);
        r[5][l] = 2.0 * (y * z - w * x);
        r[6][l] = 2.0 * (x * z - w * y);
        r[7][l] = 2.0 * (y * z + w * x);
        r[8][l] = 1.0 - 2.0 * (x * x + y * y);
    }
}

/// Rotation matrix (row-major) of a unit quaternion (w, x, y, z).
#[inline(always)]
pub fn quat_to_matrix(q: &[f32; 4], r: &mut [f32; 9]) {
    let (w, x, y, z) = (q[0], q[1], q[2], q[3]);
    r[0] = 1.0 - 2.0 * (y * y + z * z);
    r[1] = 2.0 * (x * y - w * z);
    r[2] = 2.0 * (x * z + w * y);
    r[3] = 2.0 * (x * y + w * z);
    r[4] = 1.0 - 2.0 * (x * x + z * z);
    r[5] = 2.0 * (y * z - w * x);
    r[6] = 2.0 * (x * z - w * y);
    r[7] = 2.0 * (y * z + w * x);
    r[8] = 1.0 - 2.0 * (x * x + y * y);
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
    fn polar_rotation_agrees_with_svd_rotation() {
        // Random rotations times stretches from mild to strongly anisotropic, plus an inverted
        // and a flat element (the SVD fallback).
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        for case in 0..2000 {
            let rot = Rotation3::from_euler_angles(3.0 * next(), 3.0 * next(), 3.0 * next());
            let spread = [0.01, 0.3, 0.9][case % 3];
            let s = Matrix3::from_fn(|_, _| spread * next());
            let f = rot.into_inner() * (Matrix3::identity() + (s + s.transpose()) * 0.5);
            let (a, b) = (warp_rotation_polar(&f), warp_rotation_svd(&f));
            assert!(is_proper_rotation(&a), "case {case}: {a}");
            assert!(
                (a - b).norm() < 1e-10,
                "case {case}: polar {a} vs svd {b} for F = {f}"
            );
        }
        let rot = Rotation3::from_euler_angles(0.4, 0.2, -0.7).into_inner();
        for d in [-0.3, 1e-9] {
            let f = rot * Matrix3::from_diagonal(&Vector3::new(1.0, 0.8, d));
            let (a, b) = (warp_rotation_polar(&f), warp_rotation_svd(&f));
            assert!((a - b).norm() < 1e-10, "det {d}: polar {a} vs svd {b}");
        }
        let nan = Matrix3::from_element(f64::NAN);
        assert_eq!(warp_rotation_polar(&nan), Matrix3::identity());
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

    /// A reproducible stream uniform in [-1, 1) (a 64-bit LCG from `seed`).
    fn uniform(mut seed: u64) -> impl FnMut() -> f64 {
        move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((seed >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
        }
    }

    /// The deformation F = R (I + E) of a random rotation R (Euler angles up to `angle`) and E
    /// with entries up to `stretch`; draws 3 then 9 numbers from `rnd`.
    fn random_deformation(rnd: &mut impl FnMut() -> f64, angle: f64, stretch: f64) -> Matrix3<f64> {
        let rot =
            Rotation3::from_euler_angles(angle * rnd(), angle * rnd(), angle * rnd()).into_inner();
        let mut s = Matrix3::identity();
        for v in s.iter_mut() {
            *v += stretch * rnd();
        }
        rot * s
    }

    #[test]
    fn fast_path_agrees_with_svd_and_stays_proper() {
        let mut rnd = uniform(99u64);
        for case in 0..200 {
            let f = random_deformation(&mut rnd, 1.5, 0.2);
            let f32m: [f32; 9] = core::array::from_fn(|k| f[(k / 3, k % 3)] as f32);
            let mut q = [1.0f32, 0.0, 0.0, 0.0];
            let mut r = [0.0f32; 9];
            warp_rotation_fast(&f32m, &mut q, 200, 0.0, &mut r);
            let rm = Matrix3::from_fn(|i, j| r[3 * i + j] as f64);
            assert!((rm.transpose() * rm - Matrix3::identity()).norm() < 1e-5);
            assert!((rm.determinant() - 1.0).abs() < 1e-5);
            if f.determinant() > 0.05 {
                let expect = warp_rotation_svd(&f);
                assert!((rm - expect).norm() < 1e-4, "case {case}: {rm} vs {expect}");
            }
        }
        // Inverted element: still a proper rotation.
        let f = [1.0f32, 0.0, 0.0, 0.0, 0.8, 0.0, 0.0, 0.0, -0.3];
        let mut q = [1.0f32, 0.0, 0.0, 0.0];
        let mut r = [0.0f32; 9];
        warp_rotation_fast(&f, &mut q, 100, 0.0, &mut r);
        let rm = Matrix3::from_fn(|i, j| r[3 * i + j] as f64);
        assert!((rm.determinant() - 1.0).abs() < 1e-5);
    }

    /// The lane kernel the residual pass runs against the scalar one, lane by lane, after the
    /// runtime's 2 warm-started iterations and after 100 from the identity: the same rotation to
    /// f32 round-off (the lanes normalise with their own 1/√ in plain arithmetic, the scalar one
    /// with `libm::sqrtf`), proper, and the SVD's where the element is not inverted.
    #[test]
    fn lane_kernel_agrees_with_the_scalar_one() {
        let mut rnd = uniform(2026u64);
        for case in 0..64 {
            let fs: [Matrix3<f64>; LANES] =
                core::array::from_fn(|_| random_deformation(&mut rnd, 1.5, 0.2));
            let f: [[f32; LANES]; 9] =
                core::array::from_fn(|k| core::array::from_fn(|l| fs[l][(k / 3, k % 3)] as f32));
            for iterations in [2, 100] {
                let mut q = [[0.0f32; LANES]; 4];
                q[0] = [1.0; LANES];
                let mut r = [[0.0f32; LANES]; 9];
                warp_rotation_fast_lanes(&f, &mut q, iterations, 0.0, &mut r);
                for l in 0..LANES {
                    let fl: [f32; 9] = core::array::from_fn(|k| f[k][l]);
                    let mut ql = [1.0f32, 0.0, 0.0, 0.0];
                    let mut rl = [0.0f32; 9];
                    warp_rotation_fast(&fl, &mut ql, iterations, 0.0, &mut rl);
                    let lane = Matrix3::from_fn(|i, j| r[3 * i + j][l] as f64);
                    let scalar = Matrix3::from_fn(|i, j| rl[3 * i + j] as f64);
                    assert!(
                        (lane - scalar).norm() < 1e-5,
                        "case {case} lane {l}, {iterations} iterations: {lane} vs {scalar}"
                    );
                    assert!((lane.transpose() * lane - Matrix3::identity()).norm() < 1e-5);
                    if iterations == 100 && fs[l].determinant() > 0.05 {
                        let svd = warp_rotation_svd(&fs[l]);
                        assert!((lane - svd).norm() < 1e-4, "case {case} lane {l}");
                    }
                }
            }
        }
        // The 1/√ itself, over the range a step's |q|² takes (1 + |h|², h up to 10).
        let xs: [f32; LANES] = [1.0, 1.0 + 1e-7, 1.001, 1.5, 2.0, 7.3, 42.0, 101.0];
        let y = inv_sqrt_lanes(&xs);
        for (x, y) in xs.iter().zip(y) {
            let exact = 1.0 / (*x as f64).sqrt();
            assert!(
                ((y as f64) - exact).abs() < 2e-7 * exact,
                "1/√{x}: {y} vs {exact}"
            );
        }
    }

    /// The tolerance as a tick meets it: each element warm-started from the converged rotation of
    /// its last state, then turned a little further (by 1e-6 to 0.3 rad) with a 5 % stretch. A
    /// lane stops where the scalar loop stops. Where the turn is well above the tolerance
    /// (1e-4 rad) the tick's two steps are taken, exactly as without one; where it is below, one
    /// step is taken, which leaves the rotation within the tolerance of the polar one (the SVD's)
    /// and differs from the second step's result by less than half the turn.
    #[test]
    fn the_rotation_tolerance_stops_only_converged_lanes() {
        let tolerance = 1e-4;
        let mut rnd = uniform(7u64);
        let turns = [1e-6, 1e-5, 3e-5, 1e-4, 1e-3, 1e-2, 0.1, 0.3];
        for case in 0..32 {
            let before: [Matrix3<f64>; LANES] =
                core::array::from_fn(|_| random_deformation(&mut rnd, 1.5, 0.05));
            let after: [Matrix3<f64>; LANES] = core::array::from_fn(|l| {
                let axis = Vector3::new(rnd(), rnd(), rnd()).normalize();
                Rotation3::from_scaled_axis(axis * turns[l]).into_inner() * before[l]
            });
            let lanes = |m: &[Matrix3<f64>; LANES]| -> [[f32; LANES]; 9] {
                core::array::from_fn(|k| core::array::from_fn(|l| m[l][(k / 3, k % 3)] as f32))
            };
            // Converged on the last state: the warm start a tick begins from.
            let mut q0 = [[0.0f32; LANES]; 4];
            q0[0] = [1.0; LANES];
            let mut r = [[0.0f32; LANES]; 9];
            warp_rotation_fast_lanes(&lanes(&before), &mut q0, 100, 0.0, &mut r);
            let f = lanes(&after);
            let (mut q, mut q_all) = (q0, q0);
            let mut r_all = r;
            warp_rotation_fast_lanes(&f, &mut q, 2, tolerance, &mut r);
            warp_rotation_fast_lanes(&f, &mut q_all, 2, 0.0, &mut r_all);
            for l in 0..LANES {
                let fl: [f32; 9] = core::array::from_fn(|k| f[k][l]);
                let mut ql: [f32; 4] = core::array::from_fn(|k| q0[k][l]);
                let mut rl = [0.0f32; 9];
                warp_rotation_fast(&fl, &mut ql, 2, tolerance, &mut rl);
                let lane = Matrix3::from_fn(|i, j| r[3 * i + j][l] as f64);
                let scalar = Matrix3::from_fn(|i, j| rl[3 * i + j] as f64);
                assert!(
                    (lane - scalar).norm() < 1e-6,
                    "case {case} lane {l}: {lane} vs {scalar}"
                );
                let all = Matrix3::from_fn(|i, j| r_all[3 * i + j][l] as f64);
                let turn = turns[l];
                if turn >= 10.0 * tolerance as f64 {
                    assert_eq!(lane, all, "case {case}: a turn of {turn} rad");
                } else if turn <= tolerance as f64 {
                    let polar = (lane - warp_rotation_svd(&after[l])).norm();
                    assert!(
                        polar < tolerance as f64,
                        "case {case}: a turn of {turn} rad left {polar:e} from the polar rotation"
                    );
                    let second = (lane - all).norm();
                    // One step, not two: the lane stopped.
                    assert!(
                        turn >= tolerance as f64 || turn < 1e-5 || second > 0.0,
                        "case {case}: a turn of {turn} rad took the second step"
                    );
                    assert!(
                        second < 0.5 * turn + 1e-6,
                        "case {case}: a turn of {turn} rad, the second step would move {second:e}"
                    );
                }
            }
        }
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
        let mut rnd = uniform(12345u64);
        for _ in 0..200 {
            let f = random_deformation(&mut rnd, 3.0, 0.3);
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
