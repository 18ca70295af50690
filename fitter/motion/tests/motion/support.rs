//! What the motion crate's own tests share: the bundled example dataset and the gradient check.

use std::path::{Path, PathBuf};

use palpate_fem::mesh::Mesh;
use palpate_motion::gradient::{evaluate, Method};
use palpate_motion::model::{Material, Model, Observations, Param};
use palpate_motion::scenario::{example_bar, example_truth};

/// The bundled motion dataset (`models/motion-example`: a 24-tet bar, front face clamped and
/// shaken, gravity along −y).
pub fn example() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/motion-example")
}

/// Copies the files of [`example`] into `dir`, for a test that edits one of them.
pub fn copy_example(dir: &Path) {
    for f in [
        "dataset.toml",
        "mesh.msh",
        "markers.csv",
        "trajectories.csv",
        "clamps.csv",
    ] {
        std::fs::copy(example().join(f), dir.join(f)).unwrap();
    }
}

/// The example bar ([`example_bar`]) in `cells` hexahedra for `steps` steps.
pub fn bar(cells: [usize; 3], steps: usize) -> (Mesh, Model) {
    example_bar(cells, steps).unwrap()
}

/// The example bar's material ([`example_truth`]).
pub fn truth(model: &Model) -> Material {
    example_truth(model)
}

/// The adjoint and direct gradients of Φ at `mat` with respect to `params`: the same Φ (to
/// 1e-14), the same gradient (to 1e-8 of the largest component) and both the central finite
/// difference with step `step(param, value)` (to 1e-4 of the largest component). Returns the
/// adjoint gradient and its largest component's size.
pub fn assert_gradients_agree(
    model: &Model,
    mat: &Material,
    params: &[Param],
    obs: &Observations,
    step: impl Fn(&Param, f64) -> f64,
) -> (Vec<f64>, f64) {
    let ad = evaluate(model, mat, params, obs, Some(Method::Adjoint)).unwrap();
    let di = evaluate(model, mat, params, obs, Some(Method::Direct)).unwrap();
    let (ga, gd) = (ad.grad.unwrap(), di.grad.unwrap());
    assert!((ad.phi - di.phi).abs() <= 1e-14 * ad.phi.abs());
    let scale = ga.iter().fold(0.0f64, |m, g| m.max(g.abs()));
    for (p, par) in params.iter().enumerate() {
        let q0 = mat.read(&[*par])[0];
        let h = step(par, q0);
        // The parameter moved alone, beside the regions' own values of its kind in the list:
        // a global parameter reaches the elements of the regions that have no value of its kind
        // of their own (`Material::set`).
        let own: Vec<Param> = params
            .iter()
            .copied()
            .filter(|o| par.is_global() && o.region.is_some() && o.kind == par.kind)
            .collect();
        let own_q = mat.read(&own);
        let phi = |q: f64| {
            let mut m = mat.clone();
            let list: Vec<Param> = std::iter::once(*par).chain(own.iter().copied()).collect();
            let qs: Vec<f64> = std::iter::once(q).chain(own_q.iter().copied()).collect();
            m.set(&list, &qs);
            evaluate(model, &m, params, obs, None).unwrap().phi
        };
        let fd = (phi(q0 + h) - phi(q0 - h)) / (2.0 * h);
        // Adjoint vs direct: same discrete derivative, different order of operations.
        assert!(
            (ga[p] - gd[p]).abs() <= 1e-8 * scale.max(ga[p].abs()),
            "{par:?}: adjoint {} direct {}",
            ga[p],
            gd[p]
        );
        // Analytic vs FD: relative 1e-4 of the largest component (FD truncation + Newton noise).
        assert!(
            (ga[p] - fd).abs() <= 1e-4 * scale.max(fd.abs()),
            "{par:?}: adjoint {} vs finite difference {fd} (scale {scale})",
            ga[p]
        );
    }
    (ga, scale)
}

/// The static problem of `mesh` held at its node group `clamp` under its own weight (density
/// `density`, gravity along −z), Neo-Hookean with (λ, μ): the reference the motion's static
/// start and rest are checked against.
pub fn clamped_under_gravity<'m>(
    mesh: &'m Mesh,
    clamp: &str,
    lambda: f64,
    mu: f64,
    density: f64,
) -> palpate_motion::statics::StaticProblem<'m> {
    let mut p = palpate_motion::statics::StaticProblem::new(
        mesh,
        palpate_motion::hyperelastic::HyperParams {
            lambda,
            mu,
            stiffening: 0.0,
        },
        mesh.node_groups[clamp].clone(),
    );
    p.density = density;
    p.gravity = [0.0, 0.0, -9.81];
    p
}
