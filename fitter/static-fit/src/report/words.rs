//! Words and numbers for the people who read the report: what a fit's settings mean in plain
//! words (not the Rust names of its enums), and numbers in plain notation with their unit
//! (`23.01 kPa`, `0.285`, `0.0012 N`), never `2.30144e4`.

use crate::{Layout, Method, Sets};

/// The inverse method, as the thesis names it.
pub fn method(m: Method) -> &'static str {
    match m {
        Method::Force => "force-based linear least squares (thesis §5.2)",
        Method::Displacement => "displacement-based non-linear least squares (thesis §5.3)",
    }
}

/// The material class: where the material may vary and how many parameter sets there are.
pub fn material(layout: Layout, sets: Sets) -> &'static str {
    match (layout, sets) {
        (Layout::Homogeneous, Sets::Single) => {
            "one material (E, ν) for the whole object, one parameter set for every measurement (linear)"
        }
        (Layout::Homogeneous, Sets::PerMeasurement) => {
            "one material (E, ν) for the whole object, one parameter set per measurement, blended over deformations (non-linear)"
        }
        (Layout::Inhomogeneous, Sets::Single) => {
            "one material (E, ν) per element, one parameter set for every measurement (linear)"
        }
        (Layout::Inhomogeneous, Sets::PerMeasurement) => {
            "one material (E, ν) per element, one parameter set per measurement, blended in strain space (non-linear)"
        }
    }
}

/// Digits after the decimal point that give `sig` significant digits for `v` (at least 0).
fn decimals(v: f64, sig: i32) -> usize {
    if v == 0.0 || !v.is_finite() {
        return 0;
    }
    (sig - 1 - v.abs().log10().floor() as i32).max(0) as usize
}

/// `v` with four significant digits in plain notation; outside 10⁻⁴…10⁶ as `1.234 × 10⁻⁷`
/// (a plain 0.0000001234 is harder to read than its power of ten).
pub fn plain(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let a = v.abs();
    if (1e-4..1e6).contains(&a) {
        return format!("{v:.*}", decimals(v, 4));
    }
    let exp = a.log10().floor() as i32;
    let mantissa = v / 10f64.powi(exp);
    format!("{mantissa:.3} × 10{}", superscript(exp))
}

fn superscript(n: i32) -> String {
    const DIGITS: [char; 10] = ['⁰', '¹', '²', '³', '⁴', '⁵', '⁶', '⁷', '⁸', '⁹'];
    let mut s = String::new();
    if n < 0 {
        s.push('⁻');
    }
    for c in n.unsigned_abs().to_string().chars() {
        s.push(DIGITS[c.to_digit(10).unwrap_or(0) as usize]);
    }
    s
}

/// The unit a column of stresses is printed in (Pa, kPa, MPa or GPa, chosen from the largest
/// magnitude so the column reads 1–1000) and its size in pascals.
pub fn pressure_unit(values: &[f64]) -> (&'static str, f64) {
    let max = values
        .iter()
        .filter(|v| v.is_finite())
        .fold(0.0f64, |m, v| m.max(v.abs()));
    if max >= 1e9 {
        ("GPa", 1e9)
    } else if max >= 1e6 {
        ("MPa", 1e6)
    } else if max >= 1e3 {
        ("kPa", 1e3)
    } else {
        ("Pa", 1.0)
    }
}

/// A stress with four significant digits in its own unit: `23.01 kPa`.
pub fn pressure(pa: f64) -> String {
    let (unit, size) = pressure_unit(&[pa]);
    format!("{} {unit}", plain_fixed(pa / size))
}

/// Four significant digits, plain notation, for values printed in a chosen unit (1–1000).
pub fn plain_fixed(v: f64) -> String {
    format!("{v:.*}", decimals(v, 4))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_read_as_a_person_writes_them() {
        assert_eq!(pressure(131_500.0), "131.5 kPa");
        assert_eq!(pressure(23_014.4), "23.01 kPa");
        assert_eq!(pressure(2.5e6), "2.500 MPa");
        assert_eq!(pressure(950.0), "950.0 Pa");
        // Each unit from its first value: 1 kPa is "1.000 kPa", not "1000 Pa".
        assert_eq!(pressure(1_000.0), "1.000 kPa");
        assert_eq!(pressure(5_000.0), "5.000 kPa");
        assert_eq!(plain(0.49), "0.4900");
        assert_eq!(plain(0.0012346), "0.001235");
        assert_eq!(plain(1.5e-7), "1.500 × 10⁻⁷");
        assert_eq!(plain(2.0e7), "2.000 × 10⁷");
        assert_eq!(plain(0.0), "0");
        assert_eq!(pressure_unit(&[11_883.5, 41_675.0]), ("kPa", 1e3));
    }

    #[test]
    fn settings_are_words_not_type_names() {
        for layout in [Layout::Homogeneous, Layout::Inhomogeneous] {
            for sets in [Sets::Single, Sets::PerMeasurement] {
                let s = material(layout, sets);
                assert!(!s.contains(&format!("{layout:?}")) && !s.contains(&format!("{sets:?}")));
            }
        }
        assert!(!method(Method::Force).contains("Force"));
        assert!(!method(Method::Displacement).contains("Displacement"));
    }
}
