//! Force-based inverse (seed 000 §5.2): substituting a measured deformation x̄ into
//! K'(p) x̄ − K''(p) x₀ = f̄ gives a system linear in p (eqs. 5.15–5.21):
//!
//! Σ_e λ_e s_e + α_e t_e = f̄,  s_e = R_e C_e (R_eᵀ x̄_e − x₀e),  t_e = R_e D_e (R_eᵀ x̄_e − x₀e)
//!
//! (eqs. 5.18–5.19; with R_e = I, eqs. 5.28–5.29). Rotations come from the measured state. Only
//! the free dofs give equations (the forces on fixed nodes are unknown reactions). Stacked with the
//! smoothness rows (eqs. 5.26, 5.34, 5.46, 5.50, 5.58) the system is solved in the least-squares
//! sense by a sparse QR factorisation (faer) of the column-equilibrated matrix, which avoids
//! squaring the condition number as the normal equations would.

use faer::linalg::solvers::SolveLstsq;
use faer::sparse::{SparseColMat, Triplet};
use faer::MatMut;
use nalgebra::{Matrix3, SVector};

use palpate_fem::forward::{Material, StaticProblem};

use super::regularisation::{sets_roughness, spatial_pairs};
use super::{FitError, Gammas, Layout, Sets};

/// Options of the force-based fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForceOptions {
    /// Homogeneous or inhomogeneous.
    pub layout: Layout,
    /// One set or one per measurement.
    pub sets: Sets,
    /// Warped (eqs. 5.18–5.19) or linear (eqs. 5.28–5.29).
    pub warp: bool,
    /// Regularisation weights (N/Pa: they weigh parameter differences in Pa against force
    /// residuals in N).
    pub gammas: Gammas,
}

/// Result of one force-based solve.
#[derive(Debug, Clone)]
pub struct ForceFit {
    /// Fitted sets.
    pub params: Vec<Material>,
    /// ‖A_i p − f̄_i‖ per measurement (N).
    pub force_residuals: Vec<f64>,
    /// Σ over sets of ‖L_s l‖ and ‖L_s a‖ (Pa).
    pub roughness: [f64; 2],
}

/// The element vectors s_e and t_e (eqs. 5.18–5.19) of one deformed state.
pub fn element_vectors(
    problem: &StaticProblem,
    x: &[[f64; 3]],
    rotations: &[Matrix3<f64>],
) -> Vec<(SVector<f64, 12>, SVector<f64, 12>)> {
    (0..problem.element_count())
        .map(|e| {
            let r = &rotations[e];
            let u = problem.unrotated_displacement(e, r, x);
            (
                palpate_fem::forward::rotate_vec(r, &(problem.c[e] * u)),
                palpate_fem::forward::rotate_vec(r, &(problem.d[e] * u)),
            )
        })
        .collect()
}

/// Fits the force-based inverse to full deformed states `xbar[i]` (every node) and full nodal
/// force vectors `forces[i]` (3n).
pub fn fit_force(
    problem: &StaticProblem,
    xbar: &[Vec<[f64; 3]>],
    forces: &[Vec<f64>],
    opts: &ForceOptions,
) -> Result<ForceFit, FitError> {
    let n_meas = xbar.len();
    if n_meas == 0 || forces.len() != n_meas {
        return Err(FitError::Input(format!(
            "{} deformations but {} force vectors",
            n_meas,
            forces.len()
        )));
    }
    let t = problem.element_count();
    let slots = match opts.layout {
        Layout::Homogeneous => 1,
        Layout::Inhomogeneous => t,
    };
    let n_sets = match opts.sets {
        Sets::Single => 1,
        Sets::PerMeasurement => n_meas,
    };
    let per_type = n_sets * slots;
    let ncols = 2 * per_type;
    let col = |ty: usize, set: usize, slot: usize| ty * per_type + set * slots + slot;
    let nd = problem.free_dofs();

    // Data rows.
    let mut trip: Vec<Triplet<usize, usize, f64>> = Vec::new();
    let mut rhs: Vec<f64> = Vec::with_capacity(nd * n_meas);
    let mut vectors = Vec::with_capacity(n_meas);
    for (i, (x, f)) in xbar.iter().zip(forces).enumerate() {
        if x.len() != problem.node_count() || f.len() != 3 * problem.node_count() {
            return Err(FitError::Input(format!(
                "measurement {i}: state or force vector has the wrong length"
            )));
        }
        let rot = problem.rotations(x, opts.warp);
        let st = element_vectors(problem, x, &rot);
        let set = if n_sets == 1 { 0 } else { i };
        for (e, (s, tv)) in st.iter().enumerate() {
            let slot = if slots == 1 { 0 } else { e };
            for (k, &node) in problem.tets[e].iter().enumerate() {
                let fi = problem.free_index[node];
                if fi == usize::MAX {
                    continue;
                }
                for d in 0..3 {
                    let row = i * nd + 3 * fi + d;
                    trip.push(Triplet::new(row, col(0, set, slot), s[3 * k + d]));
                    trip.push(Triplet::new(row, col(1, set, slot), tv[3 * k + d]));
                }
            }
        }
        rhs.extend(problem.gather_free(f));
        vectors.push(st);
    }
    let data_rows = nd * n_meas;
    // Column equilibration from the data part.
    let mut colsq = vec![0.0; ncols];
    {
        let a = SparseColMat::<usize, f64>::try_new_from_triplets(data_rows, ncols, &trip)
            .map_err(|e| FitError::Input(format!("building A: {e:?}")))?;
        let (cp, v) = (a.symbolic().col_ptr().to_vec(), a.val());
        for j in 0..ncols {
            colsq[j] = v[cp[j]..cp[j + 1]].iter().map(|x| x * x).sum();
        }
    }
    let scale: Vec<f64> = colsq
        .iter()
        .map(|&s| if s > 0.0 { 1.0 / s.sqrt() } else { 1.0 })
        .collect();
    for tr in trip.iter_mut() {
        tr.val *= scale[tr.col];
    }
    // Regularisation rows.
    let mut row = data_rows;
    let g = opts.gammas;
    if opts.layout == Layout::Inhomogeneous {
        let pairs = spatial_pairs(&problem.tets);
        for (ty, gs) in [(0, g.s_lambda), (1, g.s_alpha)] {
            if gs <= 0.0 {
                continue;
            }
            for set in 0..n_sets {
                for &(a, b) in &pairs {
                    let (ca, cb) = (col(ty, set, a), col(ty, set, b));
                    trip.push(Triplet::new(row, ca, gs * scale[ca]));
                    trip.push(Triplet::new(row, cb, -gs * scale[cb]));
                    row += 1;
                }
            }
        }
    }
    if n_sets > 1 {
        for (ty, gm) in [(0, g.m_lambda), (1, g.m_alpha)] {
            if gm <= 0.0 {
                continue;
            }
            for set in 0..n_sets - 1 {
                for slot in 0..slots {
                    let (ca, cb) = (col(ty, set, slot), col(ty, set + 1, slot));
                    trip.push(Triplet::new(row, ca, gm * scale[ca]));
                    trip.push(Triplet::new(row, cb, -gm * scale[cb]));
                    row += 1;
                }
            }
        }
    }
    let nrows = row;
    if nrows < ncols {
        return Err(FitError::Singular(format!(
            "{ncols} unknowns but only {nrows} equations: an inhomogeneous or per-measurement fit needs γ_s > 0 (and γ_m > 0 across measurements)"
        )));
    }
    rhs.resize(nrows, 0.0);
    let a = SparseColMat::<usize, f64>::try_new_from_triplets(nrows, ncols, &trip)
        .map_err(|e| FitError::Input(format!("building the stacked system: {e:?}")))?;
    let qr = a
        .sp_qr()
        .map_err(|e| FitError::Singular(format!("sparse QR: {e:?}")))?;
    let mut b = rhs.clone();
    qr.solve_lstsq_in_place(MatMut::from_column_major_slice_mut(&mut b, nrows, 1));
    let p: Vec<f64> = (0..ncols).map(|j| b[j] * scale[j]).collect();
    if !p.iter().all(|v| v.is_finite()) {
        return Err(FitError::Singular(
            "the least-squares solution is not finite (rank-deficient system: raise γ)".into(),
        ));
    }
    let params: Vec<Material> = (0..n_sets)
        .map(|set| Material {
            lambda: (0..slots).map(|s| p[col(0, set, s)]).collect(),
            alpha: (0..slots).map(|s| p[col(1, set, s)]).collect(),
            foundation: None,
        })
        .collect();
    // Force residuals ‖A_i p_i − f̄_i‖ over free dofs.
    let mut force_residuals = Vec::with_capacity(n_meas);
    for (i, st) in vectors.iter().enumerate() {
        let mat = &params[if n_sets == 1 { 0 } else { i }];
        let mut r: Vec<f64> = problem.gather_free(&forces[i]).iter().map(|v| -v).collect();
        for (e, (s, tv)) in st.iter().enumerate() {
            let (l, al) = mat.at(e);
            for (k, &node) in problem.tets[e].iter().enumerate() {
                let fi = problem.free_index[node];
                if fi != usize::MAX {
                    for d in 0..3 {
                        r[3 * fi + d] += l * s[3 * k + d] + al * tv[3 * k + d];
                    }
                }
            }
        }
        force_residuals.push(r.iter().map(|v| v * v).sum::<f64>().sqrt());
    }
    let rough = sets_roughness(&problem.tets, slots > 1, &params);
    Ok(ForceFit {
        params,
        force_residuals,
        roughness: rough,
    })
}
