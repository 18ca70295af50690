//! The element state: connectivity, rest shape-function gradients and volumes, the material
//! parameters in force, and the per-element rotations of stiffness warping.
//!
//! This room changes when what the runtime knows per element changes. Element arrays are padded
//! to whole [`LANES`] blocks ([`crate::storage::padded_elements`]) and the 9-, 4- and 9-value
//! arrays (∇φ, quaternion, R, R∇φ) are blocked by [`LANES`] (see [`blk`]) so the batched kernels
//! load one value of eight elements with one vector load.

use crate::element::{element_cd, pack_symmetric, tet_geometry, ElementDefect, PACKED_LEN};
use crate::error::RuntimeError;
use crate::kernel::{gradient_of_lanes, rotate_gradients_lanes, LANES, M3};
use crate::rotation::warp_rotation_fast_lanes;
use crate::storage::{Carver, Dims, RoomLayout};
use nalgebra::Vector3;
use palpate_protocol::model::{ModelRecord, ParameterLayout};

/// Index of value `k` (of `width`) of element `e` in a LANES-blocked per-element array: blocks of
/// LANES elements, each holding value 0 of all its lanes, then value 1, … so the batched kernels
/// load each value of eight elements with one vector load.
#[inline(always)]
pub(crate) fn blk(e: usize, k: usize, width: usize) -> usize {
    (e / LANES) * width * LANES + k * LANES + e % LANES
}

/// Block `b` of a LANES-blocked per-element array of `W` values per element (see [`blk`]): one
/// contiguous run of `W · LANES` values.
#[inline(always)]
pub(crate) fn block<const W: usize>(arr: &[f32], b: usize) -> [[f32; LANES]; W] {
    let mut o = [[0.0f32; LANES]; W];
    let base = b * W * LANES;
    for (k, ok) in o.iter_mut().enumerate() {
        ok.copy_from_slice(&arr[base + k * LANES..base + (k + 1) * LANES]);
    }
    o
}

/// Writes block `b` of a LANES-blocked array (inverse of [`block`]).
#[inline(always)]
pub(crate) fn store_block<const W: usize>(arr: &mut [f32], b: usize, v: &[[f32; LANES]; W]) {
    let base = b * W * LANES;
    for (k, vk) in v.iter().enumerate() {
        arr[base + k * LANES..base + (k + 1) * LANES].copy_from_slice(vk);
    }
}

/// Per-element arrays.
pub(crate) struct ElementState<'a> {
    /// Elements t.
    pub t: usize,
    /// Elements padded to whole [`LANES`] blocks.
    pub tp: usize,
    /// Node indices, 4 per padded element, element-major (padding elements: node 0).
    pub tets: &'a mut [u32],
    /// ∇φ₁..₃ at rest (9, blocked).
    pub grad: &'a mut [f32],
    /// Rest volume V_e (1).
    pub vol: &'a mut [f32],
    /// λ_e in force (1; after blending).
    pub lam: &'a mut [f32],
    /// α_e in force (1; after blending).
    pub alp: &'a mut [f32],
    /// R_e, row-major (9, blocked).
    pub rot: &'a mut [f32],
    /// R_e as a quaternion (w, i, j, k), the warm start of its extraction (4, blocked).
    pub quat: &'a mut [f32],
    /// R_e∇φ₁..₃ for the PCG kernel (9, blocked).
    pub ghat: &'a mut [f32],
    /// Current rest-frame strain, 6 per element (unpadded; strain blending only).
    pub strain: &'a mut [f32],
    /// ‖ε_e − ē_{l,e}‖² of every fitted set l and element e at `(e, l)` → `e · sets + l`
    /// (strain blending only): the blend's per-neighbour distances, computed once per blend,
    /// element-major so that one neighbour's distances to every set are adjacent.
    pub strain_distance: &'a mut [f32],
    /// The model's C_e and D_e, 2 × 78 per element (unpadded; packed kernel only).
    pub cd: &'a mut [f32],
}

impl<'a> ElementState<'a> {
    /// The room's arrays, in carving order (see [`crate::storage::Layout`]).
    pub(crate) const fn layout(d: &Dims) -> RoomLayout<10, 1> {
        let tp = d.padded;
        RoomLayout {
            f32s: [
                9 * tp,
                tp,
                tp,
                tp,
                9 * tp,
                4 * tp,
                9 * tp,
                if d.strain { 6 * d.elements } else { 0 },
                if d.strain {
                    d.blend_sets * d.elements
                } else {
                    0
                },
                if d.packed {
                    2 * PACKED_LEN * d.elements
                } else {
                    0
                },
            ],
            u32s: [4 * tp],
        }
    }

    /// Cuts the room from the pools (zeroed).
    pub(crate) fn carve(
        layout: RoomLayout<10, 1>,
        d: &Dims,
        f: &mut Carver<'a, f32>,
        u: &mut Carver<'a, u32>,
    ) -> Result<Self, RuntimeError> {
        let ([grad, vol, lam, alp, rot, quat, ghat, strain, strain_distance, cd], [tets]) =
            layout.carve(f, u)?;
        Ok(Self {
            t: d.elements,
            tp: d.padded,
            tets,
            grad,
            vol,
            lam,
            alp,
            rot,
            quat,
            ghat,
            strain,
            strain_distance,
            cd,
        })
    }

    /// Copies the model's connectivity (indices checked against the `n` nodes).
    pub(crate) fn load_tets(
        &mut self,
        rec: &ModelRecord<'_>,
        n: usize,
    ) -> Result<(), RuntimeError> {
        for (i, idx) in rec.tets.iter().enumerate() {
            RuntimeError::check_index("tets", i, idx, n)?;
            self.tets[i] = idx;
        }
        Ok(())
    }

    /// ∇φ and V_e from the rest positions `x0` with the shared element kernels, and the check
    /// that the model's C_e/D_e are those of this geometry (eq. 3.63, relative 1e-3), so what
    /// runs is what was fitted. Keeps C_e/D_e for the packed kernel.
    pub(crate) fn load_geometry(
        &mut self,
        rec: &ModelRecord<'_>,
        x0: &[f32],
    ) -> Result<(), RuntimeError> {
        for e in 0..self.t {
            let ids = self.element_ids(e);
            if ids[0] == ids[1]
                || ids[0] == ids[2]
                || ids[0] == ids[3]
                || ids[1] == ids[2]
                || ids[1] == ids[3]
                || ids[2] == ids[3]
            {
                return Err(RuntimeError::BadElement { element: e });
            }
            let xs = ids.map(|i| {
                Vector3::new(x0[3 * i] as f64, x0[3 * i + 1] as f64, x0[3 * i + 2] as f64)
            });
            let geo = tet_geometry(&xs)
                .map_err(|_: ElementDefect| RuntimeError::BadElement { element: e })?;
            for a in 0..3 {
                for k in 0..3 {
                    self.grad[blk(e, 3 * a + k, 9)] = geo.grad[a + 1][k] as f32;
                }
            }
            self.vol[e] = geo.volume as f32;
            // C_e, D_e of the model must be those of this geometry (eq. 3.63).
            let (c, d) = element_cd(&geo);
            let mut cp = [0.0f64; PACKED_LEN];
            let mut dp = [0.0f64; PACKED_LEN];
            pack_symmetric(&c, &mut cp);
            pack_symmetric(&d, &mut dp);
            let scale = cp.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-300);
            let mut worst = 0.0f64;
            for k in 0..PACKED_LEN {
                let mc = rec.c_packed.get(PACKED_LEN * e + k).unwrap_or(f32::NAN) as f64;
                let md = rec.d_packed.get(PACKED_LEN * e + k).unwrap_or(f32::NAN) as f64;
                let dc = (mc - cp[k]).abs() / scale;
                let dd = (md - dp[k]).abs() / scale;
                let w = if dc.is_nan() || dd.is_nan() {
                    f64::INFINITY
                } else {
                    dc.max(dd)
                };
                worst = worst.max(w);
                if !self.cd.is_empty() {
                    self.cd[2 * PACKED_LEN * e + k] = mc as f32;
                    self.cd[2 * PACKED_LEN * e + PACKED_LEN + k] = md as f32;
                }
            }
            if worst > 1e-3 {
                return Err(RuntimeError::InconsistentElementMatrix {
                    element: e,
                    relative_difference: worst as f32,
                });
            }
        }
        Ok(())
    }

    /// Checks every parameter set (λ > 0, −1 < α/λ < 0.5, finite) and starts from set 0;
    /// blending (if any) replaces it from the first tick on.
    pub(crate) fn load_parameters(&mut self, rec: &ModelRecord<'_>) -> Result<(), RuntimeError> {
        let ps = rec.parameters;
        let per_element = ps.layout == ParameterLayout::PerElement;
        for s in 0..ps.count as usize {
            for e in 0..if per_element { self.t } else { 1 } {
                let k = if per_element { s * self.t + e } else { s };
                let (l, a) = (
                    ps.lambda.get(k).unwrap_or(f32::NAN),
                    ps.alpha.get(k).unwrap_or(f32::NAN),
                );
                let nu = a / l;
                if !(l.is_finite() && a.is_finite() && l > 0.0 && nu > -1.0 && nu < 0.5) {
                    return Err(RuntimeError::UnphysicalParameters { set: s, element: e });
                }
            }
        }
        for e in 0..self.t {
            let k = if per_element { e } else { 0 };
            self.lam[e] = ps.lambda.get(k).unwrap_or(0.0);
            self.alp[e] = ps.alpha.get(k).unwrap_or(0.0);
        }
        Ok(())
    }

    /// Identity rotations (the rest state): R_e = I, q_e = 1, R∇φ = ∇φ.
    pub(crate) fn reset_rotations(&mut self) {
        for e in 0..self.tp {
            for k in 0..9 {
                self.rot[blk(e, k, 9)] = if k % 4 == 0 { 1.0 } else { 0.0 };
            }
            for k in 0..4 {
                self.quat[blk(e, k, 4)] = if k == 0 { 1.0 } else { 0.0 };
            }
        }
        self.ghat.copy_from_slice(self.grad);
    }

    /// The largest rotation angle (rad) of the R_e in force, 2 acos(|w| / ‖q‖) over the elements'
    /// quaternions (0 at rest): one scan of one value in four, for the load-increment rule of a
    /// tick whose load change is large ([`crate::tick`]).
    ///
    /// The scan takes the least w² / ‖q‖² and one square root at the end, not a square root per
    /// element: with a `libm::sqrtf` (a legacy-SSE `sqrtss`) between the blocks' 256-bit loads
    /// the scan took about 300 cycles an element on an Intel core, 0.6 ms of a 5k-tet crossing
    /// tick — the cost of an AVX–SSE transition, which AMD cores do not charge (BENCHMARKS.md,
    /// "Five rounds on an Intel machine of the kind").
    pub(crate) fn largest_rotation(&self) -> f32 {
        let mut min_cos2 = 1.0f32;
        for b in 0..self.tp / LANES {
            let q = block::<4>(self.quat, b);
            for l in 0..LANES.min(self.t.saturating_sub(b * LANES)) {
                let w2 = q[0][l] * q[0][l];
                let n2 = w2 + q[1][l] * q[1][l] + q[2][l] * q[2][l] + q[3][l] * q[3][l];
                if n2 > 0.0 && n2.is_finite() {
                    min_cos2 = min_cos2.min(w2 / n2);
                }
            }
        }
        2.0 * libm::acosf(libm::sqrtf(min_cos2).clamp(0.0, 1.0))
    }

    /// Node ids of the elements of block `b` and the nodal values of `src` (3 per node) there.
    #[inline(always)]
    pub(crate) fn gather_nodes(
        &self,
        b: usize,
        src: &[f32],
    ) -> ([[usize; LANES]; 4], [[[f32; LANES]; 3]; 4]) {
        let mut ids = [[0usize; LANES]; 4];
        let mut v = [[[0.0f32; LANES]; 3]; 4];
        let tets = &self.tets[4 * LANES * b..4 * LANES * (b + 1)];
        for l in 0..LANES {
            for a in 0..4 {
                let i = tets[4 * l + a] as usize;
                ids[a][l] = i;
                // One bounds check per node (ids < n by construction).
                if let Some(x) = src.get(3 * i..3 * i + 3) {
                    v[a][0][l] = x[0];
                    v[a][1][l] = x[1];
                    v[a][2][l] = x[2];
                }
            }
        }
        (ids, v)
    }

    /// V_e, λ_e, α_e of the elements of block `b`.
    #[inline(always)]
    #[allow(clippy::type_complexity)]
    pub(crate) fn block_material(&self, b: usize) -> ([f32; LANES], [f32; LANES], [f32; LANES]) {
        let e0 = b * LANES;
        let mut vol = [0.0f32; LANES];
        let mut lam = [0.0f32; LANES];
        let mut alp = [0.0f32; LANES];
        vol.copy_from_slice(&self.vol[e0..e0 + LANES]);
        lam.copy_from_slice(&self.lam[e0..e0 + LANES]);
        alp.copy_from_slice(&self.alp[e0..e0 + LANES]);
        (vol, lam, alp)
    }

    /// Node ids of element `e`.
    #[inline(always)]
    pub(crate) fn element_ids(&self, e: usize) -> [usize; 4] {
        [
            self.tets[4 * e] as usize,
            self.tets[4 * e + 1] as usize,
            self.tets[4 * e + 2] as usize,
            self.tets[4 * e + 3] as usize,
        ]
    }

    /// ∇φ₁..₃ of element `e`.
    #[inline(always)]
    pub(crate) fn element_grad(&self, e: usize) -> [f32; 9] {
        core::array::from_fn(|k| self.grad[blk(e, k, 9)])
    }

    /// R_e of element `e` (row-major).
    #[inline(always)]
    pub(crate) fn element_rot(&self, e: usize) -> M3 {
        core::array::from_fn(|k| self.rot[blk(e, k, 9)])
    }

    /// R_e from the displacements `u` (eqs. 3.55–3.58, `iters` warm-started iterations) when
    /// `warp` (each element's extraction stopping early at `tolerance`, see
    /// [`crate::RuntimeConfig::rotation_tolerance`]), and, for strain blending, ε_e (eq. 6.8) —
    /// also without warping (R_e = I), where ε_e is the linear strain sym(H). Runs LANES elements
    /// at a time (SIMD). Returns an upper bound of how far (rad) any rotation moved.
    #[inline(never)]
    pub(crate) fn update_rotations(
        &mut self,
        u: &[f32],
        warp: bool,
        iters: usize,
        tolerance: f32,
    ) -> f32 {
        let mut moved = 0.0f32;
        let want_strain = !self.strain.is_empty();
        if !warp && !want_strain {
            return moved;
        }
        for b in 0..self.tp / LANES {
            let (_, v) = self.gather_nodes(b, u);
            let g = block::<9>(self.grad, b);
            // F = I + H
            let mut f = gradient_of_lanes(&v, &g);
            for k in [0, 4, 8] {
                for fl in f[k].iter_mut() {
                    *fl += 1.0;
                }
            }
            let mut r = block::<9>(self.rot, b);
            if warp {
                let mut q = block::<4>(self.quat, b);
                moved = moved.max(warp_rotation_fast_lanes(
                    &f, &mut q, iters, tolerance, &mut r,
                ));
                store_block(self.quat, b, &q);
                store_block(self.rot, b, &r);
                store_block(self.ghat, b, &rotate_gradients_lanes(&g, &r));
            }
            if want_strain {
                // ε = sym(RᵀF) − I, engineering shear (R = I without warping).
                for l in 0..LANES {
                    let e = b * LANES + l;
                    if e >= self.t {
                        break;
                    }
                    let rt_f = |i: usize, j: usize| {
                        r[i][l] * f[j][l] + r[3 + i][l] * f[3 + j][l] + r[6 + i][l] * f[6 + j][l]
                    };
                    let s = &mut self.strain[6 * e..6 * e + 6];
                    s[0] = rt_f(0, 0) - 1.0;
                    s[1] = rt_f(1, 1) - 1.0;
                    s[2] = rt_f(2, 2) - 1.0;
                    s[3] = rt_f(0, 1) + rt_f(1, 0);
                    s[4] = rt_f(1, 2) + rt_f(2, 1);
                    s[5] = rt_f(2, 0) + rt_f(0, 2);
                }
            }
        }
        moved
    }

    /// Copies another runtime's rotations and parameters in force (same element count).
    pub(crate) fn copy_state_from(&mut self, other: &ElementState<'_>) {
        self.rot.copy_from_slice(other.rot);
        self.quat.copy_from_slice(other.quat);
        self.ghat.copy_from_slice(other.ghat);
        self.lam.copy_from_slice(other.lam);
        self.alp.copy_from_slice(other.alp);
    }
}
