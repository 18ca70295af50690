//! The warped stiffness K' = Σ R_e K_e R_eᵀ (eq. 3.52), matrix-free: its product (the PCG's
//! [`LinearOperator`]), the residual pass r_full = f − f_int(x) with the preconditioner's node
//! blocks, and the element-force buffer both sum through.
//!
//! This room changes when the way K' is applied or assembled changes.

use crate::config::Kernel;
use crate::element_state::{block, store_block, ElementState};
use crate::error::RuntimeError;
use crate::kernel::{
    diagonal_blocks_lanes, gradient_of_lanes, rotate_gradients_lanes, rotated_apply_lanes,
    warped_apply_packed, warped_internal_force, warped_internal_force_from_h_lanes, LANES,
};
use crate::pcg::LinearOperator;
use crate::rotation::warp_rotation_fast_lanes;
use crate::storage::{Carver, Dims, RoomLayout};

#[inline(always)]
fn gather(v: &[f32], ids: &[usize; 4]) -> [[f32; 3]; 4] {
    let mut o = [[0.0f32; 3]; 4];
    for a in 0..4 {
        let i = 3 * ids[a];
        o[a] = [v[i], v[i + 1], v[i + 2]];
    }
    o
}

#[inline(always)]
fn scatter_add(v: &mut [f32], ids: &[usize; 4], f: &[[f32; 3]; 4]) {
    for a in 0..4 {
        let i = 3 * ids[a];
        v[i] += f[a][0];
        v[i + 1] += f[a][1];
        v[i + 2] += f[a][2];
    }
}

/// Element forces of the last element pass and the node → element-force incidences that sum
/// them: element forces go to a buffer with plain vector stores and each node gathers its own,
/// instead of a scatter whose read-modify-writes to shared nodes form store-to-load dependency
/// chains (96 per block).
pub(crate) struct ElementForces<'a> {
    /// Element forces, 12 per padded element, blocked by LANES (x, y, z of corner a at
    /// (3a + k)·LANES within the block).
    pub ef: &'a mut [f32],
    /// Node i's incidences are `inc[inc_start[i]..inc_start[i + 1]]` (n + 1 values).
    pub inc_start: &'a mut [u32],
    /// Each the index in `ef` of one (element, corner)'s x component (y and z follow at +LANES,
    /// +2·LANES); 4 per padded element.
    pub inc: &'a mut [u32],
}

impl<'a> ElementForces<'a> {
    /// The room's arrays, in carving order (see [`crate::storage::Layout`]).
    pub(crate) const fn layout(d: &Dims) -> RoomLayout<1, 2> {
        RoomLayout {
            f32s: [12 * d.padded],
            u32s: [d.nodes + 1, 4 * d.padded],
        }
    }

    /// Cuts the room from the pools (zeroed).
    pub(crate) fn carve(
        layout: RoomLayout<1, 2>,
        f: &mut Carver<'a, f32>,
        u: &mut Carver<'a, u32>,
    ) -> Result<Self, RuntimeError> {
        let ([ef], [inc_start, inc]) = layout.carve(f, u)?;
        Ok(Self { ef, inc_start, inc })
    }

    /// Fills the incidence lists of the elements' corners (counting sort by node); `cursor`
    /// (n values) is scratch.
    pub(crate) fn build(&mut self, elements: &ElementState<'_>, n: usize, cursor: &mut [u32]) {
        let t = elements.t;
        let start = &mut *self.inc_start;
        start.iter_mut().for_each(|v| *v = 0);
        for &i in &elements.tets[..4 * t] {
            start[i as usize + 1] += 1;
        }
        for i in 0..n {
            start[i + 1] += start[i];
        }
        cursor.copy_from_slice(&start[..n]);
        for e in 0..t {
            for a in 0..4 {
                let i = elements.tets[4 * e + a] as usize;
                let pos = (e / LANES) * 12 * LANES + 3 * a * LANES + e % LANES;
                self.inc[cursor[i] as usize] = pos as u32;
                cursor[i] += 1;
            }
        }
    }

    /// Stores block `b`'s element forces (plain vector stores; see [`Self::node_force`]).
    #[inline(always)]
    fn store(&mut self, b: usize, f: &[[[f32; LANES]; 3]; 4]) {
        let ef = &mut self.ef[12 * LANES * b..12 * LANES * (b + 1)];
        for a in 0..4 {
            for k in 0..3 {
                ef[(3 * a + k) * LANES..(3 * a + k + 1) * LANES].copy_from_slice(&f[a][k]);
            }
        }
    }

    /// Σ of the stored element forces on node `i` over its incidences: a gather with
    /// independent sums.
    #[inline(always)]
    fn node_force(&self, i: usize) -> [f32; 3] {
        let (s, e) = (self.inc_start[i] as usize, self.inc_start[i + 1] as usize);
        let mut acc = [0.0f32; 3];
        for &pos in &self.inc[s..e] {
            let p = pos as usize;
            if let Some(x) = self.ef.get(p..p + 2 * LANES + 1) {
                acc[0] += x[0];
                acc[1] += x[LANES];
                acc[2] += x[2 * LANES];
            }
        }
        acc
    }
}

/// y = K' x with the rotations in force (frozen for the solve): the PCG's operator.
pub(crate) struct Stiffness<'r, 'a> {
    /// Connectivity, rotated gradients, volumes and parameters (and C_e, D_e).
    pub elements: &'r ElementState<'a>,
    /// The element-force buffer the product sums through.
    pub forces: &'r mut ElementForces<'a>,
    /// Which element kernel applies K_e.
    pub kernel: Kernel,
    /// Rotated gradients R∇φ of another state than the elements' own (a planned one,
    /// [`crate::anticipate`]), laid out like theirs; `None`: the elements' own. The packed
    /// kernel always uses the elements' own rotations.
    pub rotated: Option<&'r [f32]>,
}

/// What a residual pass keeps of the rotations it extracts.
pub(crate) enum KeepRotations<'x> {
    /// Everything, as the state's rotations (quaternions, R, R∇φ).
    State,
    /// Only the rotated gradients R∇φ, into this array (laid out like the elements'): the
    /// residual and operator of a state the runtime is not in.
    Gradients(&'x mut [f32]),
}

impl LinearOperator for Stiffness<'_, '_> {
    /// q = K' p (matrix-free, all elements). The gradient kernel runs [`LANES`] elements at a
    /// time (structure-of-arrays, SIMD); the packed kernel runs element by element.
    #[inline(never)]
    fn apply(&mut self, p: &[f32], q: &mut [f32]) {
        let el = self.elements;
        if self.kernel == Kernel::Packed {
            q.iter_mut().for_each(|v| *v = 0.0);
            for e in 0..el.t {
                let ids = el.element_ids(e);
                let r = el.element_rot(e);
                let v = gather(p, &ids);
                let base = 2 * 78 * e;
                let c: &[f32; 78] = el.cd[base..base + 78].try_into().unwrap_or(&[0.0; 78]);
                let d: &[f32; 78] = el.cd[base + 78..base + 156]
                    .try_into()
                    .unwrap_or(&[0.0; 78]);
                let f = warped_apply_packed(&v, c, d, &r, el.lam[e], el.alp[e]);
                scatter_add(q, &ids, &f);
            }
            return;
        }
        for b in 0..el.tp / LANES {
            let (_, v) = el.gather_nodes(b, p);
            let gh = block::<9>(self.rotated.unwrap_or(el.ghat), b);
            let (vol, lam, alp) = el.block_material(b);
            let f = rotated_apply_lanes(&v, &gh, &vol, &lam, &alp);
            self.forces.store(b, &f);
        }
        for (i, qi) in q.chunks_exact_mut(3).enumerate() {
            qi.copy_from_slice(&self.forces.node_force(i));
        }
    }
}

/// One pass over the elements, LANES at a time (SIMD; padding elements contribute zero):
/// r_full = f_app − f_int(u) with f_int(x) = Σ R_e K_e (R_eᵀ x_e − x₀_e); with
/// `rotate = Some((iterations, tolerance))` first R_e (and R∇φ) from the current state
/// (eqs. 3.55–3.58, [`crate::RuntimeConfig::rotation_tolerance`]), fused here so u and ∇φ are
/// gathered once; with `diag` the 3 × 3 node blocks of K' (6 values per node, added to what it
/// holds) for the preconditioner. Returns an upper bound of how far (rad) any
/// rotation moved. `keep` says what becomes of the rotations: the state's own, or — for the
/// residual of a state the runtime is not in (what a planned step would leave,
/// [`crate::anticipate`]) — only their rotated gradients.
#[inline(never)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn residual_pass(
    elements: &mut ElementState<'_>,
    forces: &mut ElementForces<'_>,
    u: &[f32],
    f_app: &[f32],
    r_full: &mut [f32],
    rotate: Option<(usize, f32)>,
    mut diag: Option<&mut [f32]>,
    mut keep: KeepRotations<'_>,
) -> f32 {
    let mut moved = 0.0f32;
    for b in 0..elements.tp / LANES {
        let (ids, v) = elements.gather_nodes(b, u);
        let g = block::<9>(elements.grad, b);
        let mut r = block::<9>(elements.rot, b);
        let (vol, lam, alp) = elements.block_material(b);
        let h = gradient_of_lanes(&v, &g);
        if let Some((iters, tolerance)) = rotate {
            let mut f = h;
            for k in [0, 4, 8] {
                for fl in f[k].iter_mut() {
                    *fl += 1.0;
                }
            }
            let mut q = block::<4>(elements.quat, b);
            moved = moved.max(warp_rotation_fast_lanes(
                &f, &mut q, iters, tolerance, &mut r,
            ));
            match &mut keep {
                KeepRotations::State => {
                    store_block(elements.quat, b, &q);
                    store_block(elements.rot, b, &r);
                    store_block(elements.ghat, b, &rotate_gradients_lanes(&g, &r));
                }
                KeepRotations::Gradients(ghat) => {
                    store_block(ghat, b, &rotate_gradients_lanes(&g, &r));
                }
            }
        }
        let f = warped_internal_force_from_h_lanes(&h, &g, &r, &vol, &lam, &alp);
        forces.store(b, &f);
        if let Some(blocks) = diag.as_deref_mut() {
            let d = diagonal_blocks_lanes(&g, &r, &vol, &lam, &alp);
            for l in 0..LANES {
                for a in 0..4 {
                    if let Some(x) = blocks.get_mut(6 * ids[a][l]..6 * ids[a][l] + 6) {
                        for j in 0..6 {
                            x[j] += d[a][j][l];
                        }
                    }
                }
            }
        }
    }
    for (i, (r, a)) in r_full
        .chunks_exact_mut(3)
        .zip(f_app.chunks_exact(3))
        .enumerate()
    {
        let fi = forces.node_force(i);
        for ((r, a), f) in r.iter_mut().zip(a).zip(fi) {
            *r = a - f;
        }
    }
    moved
}

/// Internal elastic forces f_int(x) = Σ R_e K_e (R_eᵀ x_e − x₀_e) of the displacements `u` with
/// the rotations in force, element by element (3 per node, N), into `out` (zeroed first).
pub(crate) fn internal_forces(elements: &ElementState<'_>, u: &[f32], out: &mut [f32]) {
    out.iter_mut().for_each(|v| *v = 0.0);
    for e in 0..elements.t {
        let ids = elements.element_ids(e);
        let g = elements.element_grad(e);
        let r = elements.element_rot(e);
        let uv = gather(u, &ids);
        let (f, _) = warped_internal_force(
            &uv,
            &g,
            &r,
            elements.vol[e],
            elements.lam[e],
            elements.alp[e],
        );
        scatter_add(out, &ids, &f);
    }
}
