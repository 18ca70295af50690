//! Words for the people who read the report: what a fit's settings mean in plain words (not the
//! Rust names of its enums); numbers come from [`palpate_fem::numbers`], as in every report.

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

pub use palpate_fem::numbers::{plain, plain_fixed, pressure, pressure_unit};

#[cfg(test)]
mod tests {
    use super::*;

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
