//! Small rigid-body geometry shared by the offline tools: the specimens rotate their markers with
//! it and the diagnosis rotates its registration candidate's markers the same way, so both must
//! use one implementation.

use nalgebra::Vector3;

/// Rodrigues rotation of v by rotation vector w.
pub fn rotate(w: [f64; 3], v: [f64; 3]) -> [f64; 3] {
    let (w, v) = (Vector3::from(w), Vector3::from(v));
    let th = w.norm();
    if th < 1e-300 {
        return v.into();
    }
    let k = w / th;
    let kxv = k.cross(&v);
    let kdv = k.dot(&v);
    let (s, c) = th.sin_cos();
    (v * c + kxv * s + k * kdv * (1.0 - c)).into()
}

#[cfg(test)]
mod tests {
    use super::rotate;

    #[test]
    fn quarter_turn_about_z_maps_x_to_y() {
        let r = rotate([0.0, 0.0, std::f64::consts::FRAC_PI_2], [1.0, 0.0, 0.0]);
        assert!(
            (r[0]).abs() < 1e-15 && (r[1] - 1.0).abs() < 1e-15 && r[2].abs() < 1e-15,
            "{r:?}"
        );
    }

    #[test]
    fn zero_rotation_is_the_identity() {
        assert_eq!(rotate([0.0; 3], [1.0, 2.0, 3.0]), [1.0, 2.0, 3.0]);
    }
}
