//! The runtime bench's problem written for a peer code (`palpate-lab bench runtime --export-peer
//! DIR`): the same generated block, the same fixed nodes, the same material and, tick by tick,
//! the nodal forces of the contact rule (the anchor's lumped one, or the consistent one) as the
//! runtime computes them — so a peer
//! solves exactly the problem palpate's tick solves, on the same machine, back to back
//! (`fitter/lab/peers/vegafem/run.sh`).
//!
//! Files: `block.veg` (VegaFEM's volumetric mesh format: 1-based vertices and tetrahedra, an
//! E–ν material), `fixed.txt` (0-based fixed nodes, one per line), `loads.txt` (one line per
//! tick: the tick, the number of loaded nodes, then `node fx fy fz` for each; N).

use palpate_fem::block_model::BlockModel;
use palpate_runtime::contact_rule::{
    contact_weights, contact_weights_consistent, lumped_surface_areas, ContactRule,
};
use std::fmt::Write as _;
use std::path::Path;

/// Writes the block (its material `(E, ν)`), its fixed nodes and the loads of `ticks` ticks of the
/// probe path (`contact(k)`, force `force` within `radius`, spread by `rule`) into `dir`.
#[allow(clippy::too_many_arguments)]
pub fn export(
    model: &BlockModel,
    (young, poisson): (f64, f64),
    rule: ContactRule,
    ticks: usize,
    contact: impl Fn(usize) -> [f32; 3],
    force: [f32; 3],
    radius: f32,
    dir: &Path,
) -> anyhow::Result<()> {
    use anyhow::Context as _;
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let mesh = &model.mesh;
    let mut veg = format!(
        "# palpate-lab bench runtime --export-peer: {} vertices, {} tets\n\n*VERTICES\n{} 3 0 0\n",
        mesh.nodes.len(),
        mesh.tets.len(),
        mesh.nodes.len()
    );
    for (i, p) in mesh.nodes.iter().enumerate() {
        let _ = writeln!(veg, "{} {:.17e} {:.17e} {:.17e}", i + 1, p[0], p[1], p[2]);
    }
    let _ = write!(veg, "\n*ELEMENTS\nTET\n{} 4 0\n", mesh.tets.len());
    for (e, t) in mesh.tets.iter().enumerate() {
        let _ = writeln!(
            veg,
            "{} {} {} {} {}",
            e + 1,
            t[0] + 1,
            t[1] + 1,
            t[2] + 1,
            t[3] + 1
        );
    }
    // Density does not enter a static tick; Vega's format requires one.
    let _ = write!(
        veg,
        "\n*MATERIAL BODY\nENU, 1000, {young}, {poisson}\n\n*REGION\nallElements, BODY\n"
    );
    std::fs::write(dir.join("block.veg"), veg)?;
    let fixed: String = model.fixed.iter().map(|i| format!("{i}\n")).collect();
    std::fs::write(dir.join("fixed.txt"), fixed)?;
    // The runtime's rules on its rest positions (runtime.rs, compute_contact_weights): the
    // lumped weights as they are; the consistent integrals summed per node, then scaled by 1/Σ in
    // f32 as the runtime scales them.
    let n = mesh.nodes.len();
    let mut areas = vec![0.0; n];
    let pos = |i: usize| mesh.nodes[i];
    let tris = mesh.boundary_triangles();
    lumped_surface_areas(pos, tris.iter().copied(), &mut areas);
    let mut is_fixed = vec![false; n];
    for &i in &model.fixed {
        is_fixed[i] = true;
    }
    let mut loads = String::new();
    for k in 0..ticks {
        let c = contact(k);
        let c = [c[0] as f64, c[1] as f64, c[2] as f64];
        let mut weight = vec![0.0f64; n];
        let covered = match rule {
            ContactRule::Lumped => contact_weights(
                c,
                radius as f64,
                pos,
                &areas,
                |i| is_fixed[i],
                |i, w| weight[i] = w,
            ),
            ContactRule::Consistent => contact_weights_consistent(
                c,
                radius as f64,
                n,
                pos,
                tris.len(),
                |t| tris[t],
                |i| is_fixed[i],
                |i, w| weight[i] += w,
            ),
        };
        covered.map_err(|e| anyhow::anyhow!("tick {k}: the contact covers no node: {e:?}"))?;
        let row: Vec<(usize, f64)> = weight
            .iter()
            .enumerate()
            .filter(|(_, w)| **w != 0.0)
            .map(|(i, w)| (i, *w))
            .collect();
        let _ = write!(loads, "{k} {}", row.len());
        for (i, w) in row {
            // The runtime's f32 nodal force: (w · f) rounded as it rounds it.
            let f = force.map(|v| (w as f32 * v) as f64);
            let _ = write!(loads, " {i} {:e} {:e} {:e}", f[0], f[1], f[2]);
        }
        loads.push('\n');
    }
    std::fs::write(dir.join("loads.txt"), loads)?;
    Ok(())
}
