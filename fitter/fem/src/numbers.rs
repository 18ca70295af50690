//! Numbers as the people who read palpate's reports write them: plain notation with a unit chosen
//! so the figure reads 1–1000 (`23.01 kPa`, `0.285`, `12.3 µm`), never `2.30144e4`. One place, so
//! every report of every kind prints a quantity the same way.

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
    let max = largest(values);
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

fn largest(values: &[f64]) -> f64 {
    values
        .iter()
        .filter(|v| v.is_finite())
        .fold(0.0f64, |m, v| m.max(v.abs()))
}

/// The unit `v` (in the SI unit `unit`) is printed in and its size in that SI unit: pascals by
/// [`pressure_unit`], lengths (and compliances in m/N) in m, mm or µm, angles in rad or mrad;
/// any other unit (or none) as it is.
pub fn unit_for(v: f64, unit: &str) -> (String, f64) {
    let a = largest(&[v]);
    let length = |rest: &str| {
        let (prefix, size) = if a >= 1.0 || a == 0.0 {
            ("m", 1.0)
        } else if a >= 1e-3 {
            ("mm", 1e-3)
        } else {
            ("µm", 1e-6)
        };
        (format!("{prefix}{rest}"), size)
    };
    match unit {
        "Pa" => {
            let (u, size) = pressure_unit(&[v]);
            (u.into(), size)
        }
        "m" => length(""),
        "m/N" => length("/N"),
        "rad" if a < 0.1 && a > 0.0 => ("mrad".into(), 1e-3),
        u => (u.into(), 1.0),
    }
}

/// `v` (in the SI unit `unit`) with three significant digits in the unit [`unit_for`] chooses:
/// `25.6 µm`, `0.740 mrad`, `1759 kg/m³`.
pub fn quantity(v: f64, unit: &str) -> String {
    let (u, size) = unit_for(v, unit);
    let x = v / size;
    let shown = if (1e-4..1e6).contains(&x.abs()) || x == 0.0 {
        format!("{x:.*}", decimals(x, 3))
    } else {
        plain(x)
    };
    if u.is_empty() {
        shown
    } else {
        format!("{shown} {u}")
    }
}

/// A fitted value and its standard deviation in one unit chosen from the value: (`131.5 kPa`,
/// `1.2 kPa`); the deviation with two significant digits.
pub fn value_and_sd(value: f64, sd: f64, unit: &str) -> (String, String) {
    let (u, size) = unit_for(value, unit);
    let with = |s: String| {
        if u.is_empty() {
            s
        } else {
            format!("{s} {u}")
        }
    };
    let v = value / size;
    let shown = if (1e-4..1e6).contains(&v.abs()) || v == 0.0 {
        plain_fixed(v)
    } else {
        plain(v)
    };
    let d = sd / size;
    let sd_shown = if !d.is_finite() {
        "not determined".to_string()
    } else if (1e-4..1e6).contains(&d.abs()) || d == 0.0 {
        format!("{d:.*}", decimals(d, 2))
    } else {
        plain(d)
    };
    (
        with(shown),
        if d.is_finite() {
            with(sd_shown)
        } else {
            sd_shown
        },
    )
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
    fn a_fitted_value_and_its_deviation_share_a_unit_chosen_from_the_value() {
        let s = |v, sd, u| value_and_sd(v, sd, u);
        assert_eq!(
            s(131_520.0, 1_234.0, "Pa"),
            ("131.5 kPa".into(), "1.2 kPa".into())
        );
        assert_eq!(s(2.5e-4, 3.1e-5, "m"), ("250.0 µm".into(), "31 µm".into()));
        assert_eq!(
            s(0.0123, 0.0004, "m"),
            ("12.30 mm".into(), "0.40 mm".into())
        );
        assert_eq!(
            s(3.0e-5, 1.0e-6, "m/N"),
            ("30.00 µm/N".into(), "1.0 µm/N".into())
        );
        assert_eq!(
            s(0.002, 0.0005, "rad"),
            ("2.000 mrad".into(), "0.50 mrad".into())
        );
        assert_eq!(s(0.2871, 0.013, ""), ("0.2871".into(), "0.013".into()));
        assert_eq!(
            s(1_759.0, 120.0, "kg/m³"),
            ("1759 kg/m³".into(), "120 kg/m³".into())
        );
        assert_eq!(
            s(0.3, f64::NAN, ""),
            ("0.3000".into(), "not determined".into())
        );
    }
}
