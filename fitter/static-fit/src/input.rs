//! What a static fit consumes: the forward problem, the embedded markers and the measurements
//! (observed marker positions and the nodal force vector of each contact).

use palpate_fem::dataset::{Marker, StaticDataset};
use palpate_fem::forward::{Contact, Load, Material, SolveOptions, StaticProblem};

use super::{FitError, MeasurementResidual};

/// One measured contact interaction (x̄_i, f̄_i) prepared for fitting.
#[derive(Debug, Clone)]
pub struct FitMeasurement {
    /// Measurement id.
    pub id: String,
    /// The probe contact.
    pub contact: Contact,
    /// Nodal force vector f̄_i (3n, N) from the contact rule.
    pub force: Vec<f64>,
    /// Observed markers: (marker index, deformed position in m).
    pub observed: Vec<(usize, [f64; 3])>,
}

/// Everything a static fit needs.
#[derive(Debug, Clone)]
pub struct FitInput {
    /// The forward problem (mesh, fixed nodes, surface).
    pub problem: StaticProblem,
    /// Markers embedded in surface triangles.
    pub markers: Vec<Marker>,
    /// Measurements.
    pub measurements: Vec<FitMeasurement>,
    /// Marker noise σ (m) if known: scales the displacement residuals.
    pub marker_noise: Option<f64>,
}

impl FitInput {
    /// Builds the fit input from a validated dataset.
    pub fn from_dataset(ds: &StaticDataset) -> Result<Self, FitError> {
        // Data that cannot determine even one homogeneous (λ, α) pair are refused here, before
        // any solver returns its starting guess as if it were a fit.
        let findings = palpate_fem::sanity::check_static_data(ds, 2).into_result()?;
        for w in findings.warnings() {
            log::warn!("[{}] {}", w.code, w.message);
        }
        let problem = StaticProblem::new(&ds.mesh, &ds.fixed_nodes, &ds.surface)?;
        let mut measurements = Vec::with_capacity(ds.measurements.len());
        for m in &ds.measurements {
            let contact = Contact {
                point: m.contact,
                force: m.force,
                radius: m.radius,
            };
            let force = problem
                .force_vector(&Load {
                    contacts: vec![contact],
                    nodal: vec![],
                })
                .map_err(|e| FitError::Input(format!("measurement {:?}: {e}", m.id)))?;
            measurements.push(FitMeasurement {
                id: m.id.clone(),
                contact,
                force,
                observed: m.observed.clone(),
            });
        }
        if measurements.is_empty() {
            return Err(FitError::Input("the dataset has no measurements".into()));
        }
        Ok(Self {
            problem,
            markers: ds.markers.clone(),
            measurements,
            marker_noise: ds.marker_noise,
        })
    }

    /// Simulated position of marker `k` for node positions `x`.
    pub fn marker_position(&self, k: usize, x: &[[f64; 3]]) -> [f64; 3] {
        self.markers[k].interpolate(|n| x[n])
    }

    /// Marker errors (simulated − measured) of measurement `i` for node positions `x`.
    pub fn marker_errors(&self, i: usize, x: &[[f64; 3]]) -> Vec<(usize, [f64; 3])> {
        self.measurements[i]
            .observed
            .iter()
            .map(|&(k, m)| {
                let p = self.marker_position(k, x);
                (k, [p[0] - m[0], p[1] - m[1], p[2] - m[2]])
            })
            .collect()
    }

    /// Which set measurement `i` uses when there are `set_count` sets.
    pub fn set_of(i: usize, set_count: usize) -> usize {
        if set_count == 1 {
            0
        } else {
            i
        }
    }

    /// Drives the forward model with every measured contact using the fitted sets and returns the
    /// residuals per measurement and the simulated deformations.
    pub fn evaluate(
        &self,
        params: &[Material],
        options: &SolveOptions,
        force_residuals: Option<&[f64]>,
    ) -> Result<(Vec<MeasurementResidual>, Vec<Vec<[f64; 3]>>), FitError> {
        let mut res = Vec::with_capacity(self.measurements.len());
        let mut xs = Vec::with_capacity(self.measurements.len());
        for (i, m) in self.measurements.iter().enumerate() {
            let set = Self::set_of(i, params.len());
            let sol = self
                .problem
                .solve_forces(&params[set], &m.force, None, options)?
                .solution;
            let fr = force_residuals.map(|f| f[i]);
            res.push(MeasurementResidual::new(
                m.id.clone(),
                set,
                self.marker_errors(i, &sol.x),
                fr,
            ));
            xs.push(sol.x);
        }
        Ok((res, xs))
    }
}
