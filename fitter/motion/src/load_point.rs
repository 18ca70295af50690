//! Where a hanging weight acts. A weight hung from a hook or a clip is a force at the hook's
//! point, which need not be the loaded group's nodes: a hook standing off the end face by d adds
//! the moment m g d that the group's nodes cannot carry. A [`Lever`] moves a load's point of
//! application by d along the body's long axis (from the body's centroid towards the loaded
//! nodes, across gravity) and carries it as a statically equivalent set of nodal shares: the
//! group's equal shares plus a self-equilibrated correction Δw on the nodes near the load, of
//! least Σ Δw², with Σ Δw = 0 and Σ Δw_a X_a = d a (X the rest positions, a the axis). The shares
//! sum to one and their first moment is the moved point, so the point they carry follows any
//! rigid motion of those nodes, as a point fixed to them would: the lever arm turns with the end.
//! The shares are linear in d, and d = 0 is the group's own equal shares.

use nalgebra::{DMatrix, DVector, Vector3};

use super::dataset::MotionDataset;
use super::model::{DeadLoad, Model};
use super::rest_fit::{fit_shear_modulus, Design, RestSolve, RestState};
use super::MotionError;

/// A load's point of application moved off its nodes ([`lever`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Lever {
    /// The offset d along `axis` (m; positive away from the body).
    pub offset_m: f64,
    /// The unit axis (rest frame).
    pub axis: [f64; 3],
    /// Each carrying node's share of the force (they sum to one).
    pub shares: Vec<(usize, f64)>,
}

fn point(model: &Model, n: usize) -> Vector3<f64> {
    Vector3::from(model.nodes[n])
}

/// The lever of `load` on `model` with offset `offset_m`: the support is every free node within
/// the longest edge of the elements that hold a loaded node (one layer of elements round the
/// load, whatever the mesh size).
pub fn lever(model: &Model, load: &DeadLoad, offset_m: f64) -> Result<Lever, MotionError> {
    let bad = |why: String| MotionError::Invalid(format!("load {:?}: {why}", load.name));
    if load.nodes.is_empty() {
        return Err(bad("no nodes carry it".into()));
    }
    if !offset_m.is_finite() {
        return Err(bad(format!("lever offset {offset_m} m is not finite")));
    }
    let loaded: std::collections::HashSet<usize> = load.nodes.iter().copied().collect();
    let mut reach = 0.0f64;
    for t in model
        .tets
        .iter()
        .filter(|t| t.iter().any(|n| loaded.contains(n)))
    {
        for a in 0..4 {
            for b in a + 1..4 {
                reach = reach.max((point(model, t[a]) - point(model, t[b])).norm());
            }
        }
    }
    let c: Vector3<f64> = load
        .nodes
        .iter()
        .map(|&n| point(model, n))
        .sum::<Vector3<f64>>()
        / load.nodes.len() as f64;
    let body: Vector3<f64> = (0..model.nodes.len())
        .map(|n| point(model, n))
        .sum::<Vector3<f64>>()
        / model.nodes.len().max(1) as f64;
    let g = Vector3::from(model.gravity);
    let mut axis = c - body;
    if g.norm() > 0.0 {
        let up = g / g.norm();
        axis -= up * up.dot(&axis);
    }
    if axis.norm() <= 1e-9 * reach.max(1e-9) {
        return Err(bad(
            "its nodes sit over the body's centroid: no long axis to move it along".into(),
        ));
    }
    let axis = axis.normalize();
    let support: Vec<usize> = (0..model.nodes.len())
        .filter(|&n| (0..3).all(|i| model.free[3 * n + i] != usize::MAX))
        .filter(|&n| {
            load.nodes
                .iter()
                .any(|&l| (point(model, n) - point(model, l)).norm() <= reach * (1.0 + 1e-9))
        })
        .collect();
    // Least-norm Δw with Σ Δw = 0 and Σ Δw X = d a: Δw = Aᵀ (A Aᵀ)⁻¹ b, A = [1ᵀ; Xᵀ] about c.
    let a = DMatrix::from_fn(4, support.len(), |r, k| {
        if r == 0 {
            1.0
        } else {
            point(model, support[k])[r - 1] - c[r - 1]
        }
    });
    let b = DVector::from_vec(vec![
        0.0,
        offset_m * axis.x,
        offset_m * axis.y,
        offset_m * axis.z,
    ]);
    let y = (&a * a.transpose()).cholesky().ok_or_else(|| {
        bad("the nodes round it lie in one plane: they cannot carry a moment".into())
    })?;
    let dw = a.transpose() * y.solve(&b);
    let mut shares: Vec<(usize, f64)> = support.iter().copied().zip(dw.iter().copied()).collect();
    let equal = 1.0 / load.nodes.len() as f64;
    for &n in &load.nodes {
        match shares.iter_mut().find(|(m, _)| *m == n) {
            Some(s) => s.1 += equal,
            None => shares.push((n, equal)),
        }
    }
    Ok(Lever {
        offset_m,
        axis: axis.into(),
        shares,
    })
}

impl Model {
    /// Moves the point of every hanging weight (a load declared as a mass) by `offset_m` along
    /// the body's long axis ([`lever`]); 0 puts each back on its nodes.
    pub fn set_load_lever(&mut self, offset_m: f64) -> Result<(), MotionError> {
        for i in 0..self.loads.len() {
            if self.loads[i].mass.is_none() {
                continue;
            }
            self.loads[i].lever = if offset_m == 0.0 {
                None
            } else {
                Some(lever(self, &self.loads[i], offset_m)?)
            };
        }
        Ok(())
    }

    /// The lever offset of the hanging weights (m), 0 when they act on their nodes.
    pub fn load_lever(&self) -> f64 {
        self.loads
            .iter()
            .find_map(|l| l.lever.as_ref().map(|v| v.offset_m))
            .unwrap_or(0.0)
    }
}

/// The lever of the hanging weights read from where the runs came to rest ([`fit_lever`]).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LeverFit {
    /// The offset d (m).
    pub offset_m: f64,
    /// Its 1σ from the profile's curvature (m; NaN where the profile is not curved upwards).
    pub sigma_m: f64,
    /// μ refitted at d (Pa).
    pub mu: f64,
    /// The rest states' marker RMS at d (m).
    pub rms_m: f64,
    /// The same with the weights on their nodes (d = 0) (m).
    pub rms_on_nodes_m: f64,
    /// Offsets tried.
    pub evaluations: usize,
}

/// The hanging weights' lever d that best explains where the runs `sets` came to rest: their
/// rest states ([`RestState::of_dataset`], the markers' mean over the last `window` seconds)
/// fitted for μ at each trial d with Poisson's ratio held (`design`'s elements), and d taken at
/// the least summed squared marker error — a profile over d. Runs under different loads tell d
/// from μ: a lever adds a moment in proportion to the weight, a stiffer material lowers every
/// sag alike. The search steps by 2.5 % of the mesh's diagonal from d = 0 downhill until the
/// error rises (at most ±25 % of the diagonal), then takes the vertex of the parabola through
/// the least three points. An error when no run hangs a weight.
pub fn fit_lever(
    sets: &[&MotionDataset],
    design: Design,
    poisson: f64,
    mu0: f64,
    window: f64,
) -> Result<LeverFit, MotionError> {
    if !sets
        .iter()
        .any(|d| d.model.loads.iter().any(|l| l.mass.is_some()))
    {
        return Err(MotionError::Invalid(
            "no run hangs a weight (a load declared as a mass): no lever to read".into(),
        ));
    }
    let base: Vec<RestState> = sets
        .iter()
        .map(|d| RestState::of_dataset(d, window))
        .collect::<Result<_, _>>()?;
    let solve = RestSolve {
        load_steps: 4,
        tol: 1e-6,
    };
    let markers: usize = base.iter().map(|s| s.observed.len()).sum();
    let mut mu = mu0;
    let mut tried: Vec<(f64, f64, f64)> = Vec::new();
    let mut cost = |d: f64, mu: &mut f64| -> Result<f64, MotionError> {
        if let Some(&(_, c, m)) = tried.iter().find(|t| t.0 == d) {
            *mu = m;
            return Ok(c);
        }
        let states: Vec<RestState> = sets
            .iter()
            .zip(&base)
            .map(|(ds, s)| {
                let mut model = ds.model.clone();
                model.set_load_lever(d)?;
                Ok(s.with_loads_of(&model))
            })
            .collect::<Result<_, MotionError>>()?;
        let fit = fit_shear_modulus(&states, design, poisson, *mu, &solve, 12)?;
        let c: f64 = fit
            .predictions
            .iter()
            .zip(&states)
            .map(|(p, s)| p.rms(s).powi(2) * s.observed.len() as f64)
            .sum();
        *mu = fit.mu;
        tried.push((d, c, fit.mu));
        Ok(c)
    };
    let (lo, hi) = sets[0].mesh.bounds();
    let diagonal = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
    let step = 0.025 * diagonal;
    let c0 = cost(0.0, &mut mu)?;
    let mu_zero = mu;
    let up = cost(step, &mut mu)?;
    let dir = if up < c0 {
        1.0
    } else {
        mu = mu_zero;
        -1.0
    };
    let mut k = if dir > 0.0 { 1.0 } else { 0.0 };
    let mut best = if dir > 0.0 { up } else { c0 };
    while k < 10.0 {
        let next = cost(dir * (k + 1.0) * step, &mut mu)?;
        if next >= best {
            break;
        }
        best = next;
        k += 1.0;
    }
    // The vertex of the parabola through the least point and its neighbours.
    let d1 = dir * k * step;
    let (d0, d2) = (d1 - step, d1 + step);
    let (f0, f1, f2) = (cost(d0, &mut mu)?, cost(d1, &mut mu)?, cost(d2, &mut mu)?);
    let a = (f0 - 2.0 * f1 + f2) / (2.0 * step * step);
    let (mut d, mut sigma) = (d1, f64::NAN);
    if a > 0.0 {
        let vertex = d1 - (f2 - f0) / (4.0 * a * step);
        if (vertex - d1).abs() <= step {
            d = vertex;
        }
        let s2 = f1 / (3 * markers).saturating_sub(2).max(1) as f64;
        sigma = (s2 / a).sqrt();
    }
    let cd = cost(d, &mut mu)?;
    let (d, cd) = if cd <= f1 {
        (d, cd)
    } else {
        (d1, cost(d1, &mut mu)?)
    };
    let rms = |c: f64| (c / markers.max(1) as f64).sqrt();
    Ok(LeverFit {
        offset_m: d,
        sigma_m: sigma,
        mu,
        rms_m: rms(cd),
        rms_on_nodes_m: rms(c0),
        evaluations: tried.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::example_bar;

    /// The shares sum to one, their first moment is the loaded nodes' centroid moved by d along
    /// the axis, the axis lies across gravity, and d = 0 leaves the load on its nodes.
    #[test]
    fn a_lever_carries_the_moved_point() {
        let (_, mut model) = example_bar([1, 4, 1], 10).unwrap();
        model.gravity = [0.0, 0.0, -9.81];
        let free: Vec<usize> = (0..model.nodes.len())
            .filter(|&n| model.free[3 * n] != usize::MAX)
            .collect();
        // The free nodes farthest from the clamp: the bar's free end.
        let far = |n: usize| model.nodes[n][1];
        let ymax = free
            .iter()
            .map(|&n| far(n))
            .fold(f64::NEG_INFINITY, f64::max);
        let end: Vec<usize> = free.iter().copied().filter(|&n| far(n) == ymax).collect();
        model.loads = vec![DeadLoad {
            name: "weight".into(),
            nodes: end.clone(),
            force: [0.0, 0.0, -0.05],
            from_step: 0,
            mass: Some(0.05 / 9.81),
            inertia: false,
            lever: None,
        }];
        let d = 0.004;
        model.set_load_lever(d).unwrap();
        let lv = model.loads[0].lever.clone().unwrap();
        let sum: f64 = lv.shares.iter().map(|s| s.1).sum();
        assert!((sum - 1.0).abs() < 1e-12, "{sum}");
        let moment: Vector3<f64> = lv.shares.iter().map(|&(n, w)| point(&model, n) * w).sum();
        let c: Vector3<f64> =
            end.iter().map(|&n| point(&model, n)).sum::<Vector3<f64>>() / end.len() as f64;
        let want = c + Vector3::from(lv.axis) * d;
        assert!((moment - want).norm() < 1e-12, "{moment:?} vs {want:?}");
        assert!(
            lv.axis[2].abs() < 1e-12,
            "axis {:?} not across gravity",
            lv.axis
        );
        assert!(lv.axis[1] > 0.9, "axis {:?} not along the bar", lv.axis);
        // The total force is unchanged; the moment about the centroid is d × the force.
        let mut f = vec![0.0; 3 * model.nodes.len()];
        model.add_dead_loads(0, &mut f);
        let total: f64 = (0..model.nodes.len()).map(|n| f[3 * n + 2]).sum();
        assert!((total + 0.05).abs() < 1e-12, "{total}");
        model.set_load_lever(0.0).unwrap();
        assert!(model.loads[0].lever.is_none());
        assert_eq!(model.load_lever(), 0.0);
    }
}
