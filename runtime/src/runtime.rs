//! The runtime object: fixed arrays cut from caller storage, built once from a model, then driven
//! tick by tick (see [`crate::tick`]) without allocating.

use crate::config::{Kernel, RuntimeConfig};
use crate::contact_rule::{
    contact_integrals, contact_weights_by, lumped_surface_areas, ContactRule, ContactRuleError,
};
use crate::element::{element_cd, pack_symmetric, tet_geometry, ElementDefect, PACKED_LEN};
use crate::error::RuntimeError;
use crate::kernel::LANES;
use crate::storage::{Carver, StorageRequirement};
use nalgebra::Vector3;
use palpate_protocol::model::{Blend, ModelRecord, ParameterLayout};

/// Node constraint flags.
pub(crate) const FREE: u32 = 0;
pub(crate) const FIXED: u32 = 1;
pub(crate) const PROBED: u32 = 2;

/// A rigid probe that pushes the surface to a commanded position (position-driven contact).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Probe {
    /// No probe.
    None,
    /// A sphere of `radius` centred at `center`; surface nodes inside it are pushed onto its
    /// surface along the radial direction (frictionless).
    Sphere {
        /// Centre (m).
        center: [f32; 3],
        /// Radius (m).
        radius: f32,
    },
    /// A flat circular punch: its face is the disk of `radius` through `center` normal to
    /// `axis` (unit, pointing into the object); surface nodes within the disk's footprint that
    /// lie behind the face are pushed onto its plane (frictionless).
    Flat {
        /// A point of the face (m).
        center: [f32; 3],
        /// Unit push direction.
        axis: [f32; 3],
        /// Face radius (m).
        radius: f32,
    },
}

/// Outcome of one PCG solve.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SolveStatus {
    /// ‖r‖ ≤ tolerance · scale.
    Converged,
    /// The iteration budget ran out; the iterate was kept (it is usable) and the residual reported.
    BudgetExhausted,
    /// The solve produced a non-finite value or lost positive definiteness; the last good state
    /// was kept.
    Rejected,
}

/// What one tick did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TickReport {
    /// PCG iterations used.
    pub iterations: u32,
    /// ‖r‖ / scale at exit.
    pub rel_residual: f32,
    /// Solve outcome.
    pub status: SolveStatus,
    /// ‖f_applied‖ / ‖f_commanded‖ (1 when nothing is commanded).
    pub load_fraction: f32,
    /// Nodes held by the probe.
    pub contact_nodes: u32,
    /// Force the object exerts on the probe (N), what a force-feedback device renders.
    pub reaction: [f32; 3],
    /// ‖δu‖_∞ of the step (m).
    pub step: f32,
}

/// The fixed-memory warped-stiffness simulator.
pub struct Runtime<'a> {
    pub(crate) record: ModelRecord<'a>,
    pub(crate) config: RuntimeConfig,
    pub(crate) n: usize,
    pub(crate) t: usize,
    /// Elements padded to whole [`LANES`] blocks (see [`crate::storage::padded_elements`]).
    pub(crate) tp: usize,
    // per node (3 values each unless noted)
    pub(crate) x0: &'a mut [f32],
    pub(crate) u: &'a mut [f32],
    pub(crate) u_good: &'a mut [f32],
    pub(crate) f_cmd: &'a mut [f32],
    pub(crate) f_app: &'a mut [f32],
    pub(crate) r: &'a mut [f32],
    pub(crate) r_full: &'a mut [f32],
    pub(crate) z: &'a mut [f32],
    pub(crate) p: &'a mut [f32],
    pub(crate) q: &'a mut [f32],
    pub(crate) delta: &'a mut [f32],
    /// The previous tick's increment δ, the predictor's direction (see `pcg`).
    pub(crate) delta_prev: &'a mut [f32],
    pub(crate) normal: &'a mut [f32],
    pub(crate) precond: &'a mut [f32],    // 6 per node
    pub(crate) prescribed: &'a mut [f32], // 1 per node: target n·x
    pub(crate) area: &'a mut [f32],       // 1 per node
    pub(crate) flag: &'a mut [u32],       // 1 per node
    // per padded element; grad, rot and quat blocked by LANES (see `blk`)
    pub(crate) tets: &'a mut [u32], // 4, element-major
    pub(crate) grad: &'a mut [f32], // 9, blocked
    pub(crate) vol: &'a mut [f32],  // 1
    pub(crate) lam: &'a mut [f32],  // 1
    pub(crate) alp: &'a mut [f32],  // 1
    pub(crate) rot: &'a mut [f32],  // 9, blocked
    pub(crate) quat: &'a mut [f32], // 4 (w, i, j, k), blocked
    pub(crate) ghat: &'a mut [f32], // 9, blocked: R∇φ₁..₃ for the PCG kernel
    pub(crate) ef: &'a mut [f32],   // 12, blocked: element forces of the PCG product
    /// Node → element-force incidences (CSR): node i's entries are `inc[inc_start[i]..
    /// inc_start[i + 1]]`, each the index in `ef` of one (element, corner)'s x component (y and
    /// z follow at +LANES, +2·LANES).
    pub(crate) inc_start: &'a mut [u32], // n + 1
    pub(crate) inc: &'a mut [u32],  // 4 per element
    // per element (unpadded)
    pub(crate) strain: &'a mut [f32], // 6 (strain blending only)
    pub(crate) cd: &'a mut [f32],     // 156 (packed kernel only)
    pub(crate) coarse: crate::coarse::Coarse<'a>,
    pub(crate) coarse_capacity: usize,
    // state
    pub(crate) probe: Probe,
    pub(crate) probe_cmd: Probe,
    pub(crate) tick_count: u64,
    pub(crate) f_cmd_norm: f32,
    pub(crate) reaction: [f32; 3],
    pub(crate) reaction_norm: f32,
    /// Whether `precond` holds the (inverted) blocks of some recent K'.
    pub(crate) precond_valid: bool,
    /// Upper bound of how far (rad) any rotation moved since `precond` was built.
    pub(crate) precond_drift: f32,
}

/// Index of value `k` (of `width`) of element `e` in a LANES-blocked per-element array: blocks of
/// LANES elements, each holding value 0 of all its lanes, then value 1, … so the batched kernels
/// load each value of eight elements with one vector load.
#[inline(always)]
pub(crate) fn blk(e: usize, k: usize, width: usize) -> usize {
    (e / LANES) * width * LANES + k * LANES + e % LANES
}

fn shape(what: &'static str, expected: usize, found: usize) -> Result<(), RuntimeError> {
    if expected == found {
        Ok(())
    } else {
        Err(RuntimeError::ModelShape {
            what,
            expected,
            found,
        })
    }
}

impl<'a> Runtime<'a> {
    /// Builds a runtime for `record` in the caller's storage (sized by
    /// [`StorageRequirement::for_model`]). Computes ∇φ and V_e from the rest positions with the
    /// shared element kernels and checks the model's C_e/D_e against them (relative 1e-3), so what
    /// runs is what was fitted, and runs the protocol's node-coverage check
    /// ([`palpate_protocol::model::validate_node_coverage`]: a free node in no tetrahedron is
    /// [`RuntimeError::InvalidModel`]). Nothing is allocated, here or later.
    pub fn new(
        record: ModelRecord<'a>,
        f32_storage: &'a mut [f32],
        u32_storage: &'a mut [u32],
        config: RuntimeConfig,
    ) -> Result<Self, RuntimeError> {
        let n = record.node_count as usize;
        let t = record.element_count as usize;
        let tp = crate::storage::padded_elements(t);
        shape("rest_positions", 3 * n, record.rest_positions.len())?;
        shape("tets", 4 * t, record.tets.len())?;
        shape("c_packed", PACKED_LEN * t, record.c_packed.len())?;
        shape("d_packed", PACKED_LEN * t, record.d_packed.len())?;
        let per_set = match record.parameters.layout {
            ParameterLayout::Global => 1,
            ParameterLayout::PerElement => t,
        };
        let sets = record.parameters.count as usize;
        shape(
            "parameters.lambda",
            sets * per_set,
            record.parameters.lambda.len(),
        )?;
        shape(
            "parameters.alpha",
            sets * per_set,
            record.parameters.alpha.len(),
        )?;
        if sets == 0 {
            return Err(RuntimeError::ModelShape {
                what: "parameter sets",
                expected: 1,
                found: 0,
            });
        }
        let req = StorageRequirement::for_model(&record, &config);
        let mut fc = Carver::new(f32_storage, req.f32s, "f32")?;
        let mut uc = Carver::new(u32_storage, req.u32s, "u32")?;
        let strain_len = if matches!(record.blend, Blend::Strain { .. }) {
            6 * t
        } else {
            0
        };
        let cd_len = if config.kernel == Kernel::Packed {
            2 * PACKED_LEN * t
        } else {
            0
        };
        let coarse_capacity = crate::coarse::aggregate_capacity(config.coarse_aggregates, n);
        let mut rt = Runtime {
            record,
            config,
            n,
            t,
            tp,
            x0: fc.take(3 * n)?,
            u: fc.take(3 * n)?,
            u_good: fc.take(3 * n)?,
            f_cmd: fc.take(3 * n)?,
            f_app: fc.take(3 * n)?,
            r: fc.take(3 * n)?,
            r_full: fc.take(3 * n)?,
            z: fc.take(3 * n)?,
            p: fc.take(3 * n)?,
            q: fc.take(3 * n)?,
            delta: fc.take(3 * n)?,
            delta_prev: fc.take(3 * n)?,
            normal: fc.take(3 * n)?,
            precond: fc.take(6 * n)?,
            prescribed: fc.take(n)?,
            area: fc.take(n)?,
            flag: uc.take(n)?,
            tets: uc.take(4 * tp)?,
            grad: fc.take(9 * tp)?,
            vol: fc.take(tp)?,
            lam: fc.take(tp)?,
            alp: fc.take(tp)?,
            rot: fc.take(9 * tp)?,
            quat: fc.take(4 * tp)?,
            ghat: fc.take(9 * tp)?,
            ef: fc.take(12 * tp)?,
            inc_start: uc.take(n + 1)?,
            inc: uc.take(4 * tp)?,
            strain: fc.take(strain_len)?,
            cd: fc.take(cd_len)?,
            coarse: crate::coarse::Coarse::new(
                coarse_capacity,
                uc.take(n)?,
                fc.take(crate::coarse::coarse_f32s(coarse_capacity))?,
            ),
            coarse_capacity,
            probe: Probe::None,
            probe_cmd: Probe::None,
            tick_count: 0,
            f_cmd_norm: 0.0,
            reaction: [0.0; 3],
            reaction_norm: 0.0,
            precond_valid: false,
            precond_drift: 0.0,
        };
        rt.load_geometry()?;
        rt.load_parameters()?;
        // Every free node must belong to a tetrahedron (else K' is singular). The protocol's check
        // needs one bit per node of scratch: the coarse aggregate array (n u32, filled below) is
        // free until the coarse space is built.
        palpate_protocol::model::validate_node_coverage(
            &rt.record,
            bytemuck::cast_slice_mut(&mut *rt.coarse.agg),
        )
        .map_err(RuntimeError::InvalidModel)?;
        rt.build_incidence();
        let flag = &*rt.flag;
        let grad = &*rt.grad;
        rt.coarse.build(
            rt.coarse_capacity,
            rt.x0,
            |i| flag[i] == FIXED,
            &rt.tets[..4 * t],
            |e| core::array::from_fn(|k| grad[blk(e, k, 9)]),
            &rt.vol[..t],
            rt.lam,
            rt.alp,
        );
        rt.reset();
        Ok(rt)
    }

    fn load_geometry(&mut self) -> Result<(), RuntimeError> {
        let rec = self.record;
        for (i, v) in rec.rest_positions.iter().enumerate() {
            if !v.is_finite() {
                return Err(RuntimeError::NonFiniteInput {
                    what: "rest position",
                });
            }
            self.x0[i] = v;
        }
        for (i, idx) in rec.tets.iter().enumerate() {
            if idx as usize >= self.n {
                return Err(RuntimeError::IndexOutOfRange {
                    what: "tets",
                    position: i,
                    index: idx,
                    bound: self.n,
                });
            }
            self.tets[i] = idx;
        }
        for (i, idx) in rec.fixed_nodes.iter().enumerate() {
            if idx as usize >= self.n {
                return Err(RuntimeError::IndexOutOfRange {
                    what: "fixed_nodes",
                    position: i,
                    index: idx,
                    bound: self.n,
                });
            }
            self.flag[idx as usize] = FIXED;
        }
        let tri_count = rec.surface_triangles.len() / 3;
        for (i, idx) in rec.surface_triangles.iter().enumerate() {
            if idx as usize >= self.n {
                return Err(RuntimeError::IndexOutOfRange {
                    what: "surface_triangles",
                    position: i,
                    index: idx,
                    bound: self.n,
                });
            }
        }
        // Lumped surface areas (the contact rule's A_i), one triangle at a time so no n-sized f64
        // buffer is needed.
        let x0 = &*self.x0;
        let area = &mut *self.area;
        area.iter_mut().for_each(|a| *a = 0.0);
        for k in 0..tri_count {
            let s = &rec.surface_triangles;
            let tri = [0, 1, 2].map(|j| s.get(3 * k + j).unwrap_or(0) as usize);
            let mut local = [0.0f64; 3];
            let pos = |j: usize| {
                let i = tri[j];
                [x0[3 * i] as f64, x0[3 * i + 1] as f64, x0[3 * i + 2] as f64]
            };
            lumped_surface_areas(pos, [[0usize, 1, 2]], &mut local);
            for j in 0..3 {
                area[tri[j]] += local[j] as f32;
            }
        }
        for e in 0..self.t {
            let ids = [
                self.tets[4 * e] as usize,
                self.tets[4 * e + 1] as usize,
                self.tets[4 * e + 2] as usize,
                self.tets[4 * e + 3] as usize,
            ];
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
                Vector3::new(
                    self.x0[3 * i] as f64,
                    self.x0[3 * i + 1] as f64,
                    self.x0[3 * i + 2] as f64,
                )
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

    /// Fills the node → element-force incidence lists (counting sort by node; the coarse
    /// aggregate array, filled later, serves as the cursor).
    fn build_incidence(&mut self) {
        let (n, t) = (self.n, self.t);
        let start = &mut *self.inc_start;
        start.iter_mut().for_each(|v| *v = 0);
        for &i in &self.tets[..4 * t] {
            start[i as usize + 1] += 1;
        }
        for i in 0..n {
            start[i + 1] += start[i];
        }
        let cursor = &mut *self.coarse.agg;
        cursor.copy_from_slice(&start[..n]);
        for e in 0..t {
            for a in 0..4 {
                let i = self.tets[4 * e + a] as usize;
                let pos = (e / LANES) * 12 * LANES + 3 * a * LANES + e % LANES;
                self.inc[cursor[i] as usize] = pos as u32;
                cursor[i] += 1;
            }
        }
    }

    fn load_parameters(&mut self) -> Result<(), RuntimeError> {
        let ps = self.record.parameters;
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
        // Start from set 0; blending (if any) replaces it from the first tick on.
        for e in 0..self.t {
            let k = if per_element { e } else { 0 };
            self.lam[e] = ps.lambda.get(k).unwrap_or(0.0);
            self.alp[e] = ps.alpha.get(k).unwrap_or(0.0);
        }
        Ok(())
    }

    /// Returns the object to rest: zero displacement and loads, identity rotations, no probe.
    pub fn reset(&mut self) {
        for v in [
            &mut *self.u,
            &mut *self.u_good,
            &mut *self.f_cmd,
            &mut *self.f_app,
            &mut *self.delta,
            &mut *self.delta_prev,
        ] {
            v.iter_mut().for_each(|x| *x = 0.0);
        }
        for e in 0..self.tp {
            for k in 0..9 {
                self.rot[blk(e, k, 9)] = if k % 4 == 0 { 1.0 } else { 0.0 };
            }
            for k in 0..4 {
                self.quat[blk(e, k, 4)] = if k == 0 { 1.0 } else { 0.0 };
            }
        }
        self.ghat.copy_from_slice(self.grad);
        for f in self.flag.iter_mut() {
            if *f == PROBED {
                *f = FREE;
            }
        }
        self.probe = Probe::None;
        self.probe_cmd = Probe::None;
        self.f_cmd_norm = 0.0;
        self.reaction = [0.0; 3];
        self.reaction_norm = 0.0;
        self.tick_count = 0;
        self.precond_valid = false;
    }

    /// Removes every commanded load and the probe (the object relaxes over the next ticks).
    pub fn clear_loads(&mut self) {
        self.f_cmd.iter_mut().for_each(|x| *x = 0.0);
        self.f_cmd_norm = 0.0;
        self.probe_cmd = Probe::None;
    }

    /// Commands a force-driven contact: `force` (N) spread as a uniform pressure over the rest
    /// surface within `radius` of `point` by the configured contact rule
    /// ([`crate::RuntimeConfig::contact_rule`], [`crate::contact_rule`]). Replaces earlier
    /// commanded forces; incremental loading moves the applied load toward it. Returns the
    /// number of loaded nodes.
    pub fn set_contact_force(
        &mut self,
        point: [f32; 3],
        force: [f32; 3],
        radius: f32,
    ) -> Result<usize, RuntimeError> {
        if !force.iter().all(|v| v.is_finite()) {
            return Err(RuntimeError::NonFiniteInput {
                what: "contact force",
            });
        }
        let x0 = &*self.x0;
        let flag = &*self.flag;
        let area = &*self.area;
        let tris = self.record.surface_triangles;
        let f_cmd = &mut *self.f_cmd;
        f_cmd.iter_mut().for_each(|x| *x = 0.0);
        let c = [point[0] as f64, point[1] as f64, point[2] as f64];
        let pos = |i: usize| [x0[3 * i] as f64, x0[3 * i + 1] as f64, x0[3 * i + 2] as f64];
        let to_runtime = |e| match e {
            ContactRuleError::NoNodeInRadius { nearest } => RuntimeError::ContactCoversNoNode {
                nearest: nearest as f32,
            },
            ContactRuleError::BadInput => RuntimeError::NonFiniteInput {
                what: "contact point or radius",
            },
        };
        let count = match self.config.contact_rule {
            ContactRule::Lumped => contact_weights_by(
                c,
                radius as f64,
                self.n,
                pos,
                |i| area[i] as f64,
                |i| flag[i] == FIXED,
                |i, w| {
                    for k in 0..3 {
                        f_cmd[3 * i + k] = (w as f32) * force[k];
                    }
                },
            )
            .map_err(to_runtime)?,
            ContactRule::Consistent => {
                // One pass accumulating the raw integrals ∫ N_i dA, then one scaling by 1/Σ.
                let (total, _) = contact_integrals(
                    c,
                    radius as f64,
                    self.n,
                    pos,
                    tris.len() / 3,
                    |k| [0, 1, 2].map(|j| tris.get(3 * k + j).map_or(usize::MAX, |v| v as usize)),
                    |i| flag[i] == FIXED,
                    |i, l| {
                        for k in 0..3 {
                            f_cmd[3 * i + k] += (l as f32) * force[k];
                        }
                    },
                )
                .map_err(to_runtime)?;
                let inv = (1.0 / total) as f32;
                let mut count = 0;
                for f in f_cmd.chunks_exact_mut(3) {
                    if f.iter().any(|v| *v != 0.0) {
                        count += 1;
                    }
                    f.iter_mut().for_each(|v| *v *= inv);
                }
                count
            }
        };
        self.f_cmd_norm = norm(f_cmd);
        Ok(count)
    }

    /// The commanded force on `node` (N), None out of range.
    pub fn commanded_force(&self, node: usize) -> Option<[f32; 3]> {
        let f = self.f_cmd.get(3 * node..3 * node + 3)?;
        Some([f[0], f[1], f[2]])
    }

    /// Commands an explicit nodal force (N) on top of the current commanded load.
    pub fn add_nodal_force(&mut self, node: usize, force: [f32; 3]) -> Result<(), RuntimeError> {
        if node >= self.n {
            return Err(RuntimeError::NodeOutOfRange {
                node,
                nodes: self.n,
            });
        }
        if !force.iter().all(|v| v.is_finite()) {
            return Err(RuntimeError::NonFiniteInput {
                what: "nodal force",
            });
        }
        for (f, add) in self.f_cmd[3 * node..3 * node + 3].iter_mut().zip(force) {
            *f += add;
        }
        self.f_cmd_norm = norm(self.f_cmd);
        Ok(())
    }

    /// Commands the rigid probe (position-driven contact). Incremental loading moves the probe
    /// toward the command by at most `probe_step` per tick.
    pub fn set_probe(&mut self, probe: Probe) -> Result<(), RuntimeError> {
        let ok = match probe {
            Probe::None => true,
            Probe::Sphere { center, radius } => {
                center.iter().all(|v| v.is_finite()) && radius.is_finite() && radius > 0.0
            }
            Probe::Flat {
                center,
                axis,
                radius,
            } => {
                let an = libm::sqrtf(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]);
                center.iter().all(|v| v.is_finite())
                    && radius.is_finite()
                    && radius > 0.0
                    && (an - 1.0).abs() < 1e-3
            }
        };
        if !ok {
            return Err(RuntimeError::NonFiniteInput { what: "probe" });
        }
        if matches!(self.probe, Probe::None)
            || core::mem::discriminant(&self.probe) != core::mem::discriminant(&probe)
        {
            self.probe = probe;
        }
        self.probe_cmd = probe;
        Ok(())
    }

    /// Copies the simulation state (displacements, rotations, loads, probe, contact set) of
    /// another runtime of the same model, e.g. to compare solver settings on the same tick.
    pub fn copy_state_from(&mut self, other: &Runtime<'_>) -> Result<(), RuntimeError> {
        if other.n != self.n || other.t != self.t {
            return Err(RuntimeError::ModelShape {
                what: "state of another model",
                expected: self.n,
                found: other.n,
            });
        }
        self.u.copy_from_slice(other.u);
        self.delta_prev.copy_from_slice(other.delta_prev);
        self.f_cmd.copy_from_slice(other.f_cmd);
        self.f_app.copy_from_slice(other.f_app);
        self.r_full.copy_from_slice(other.r_full);
        self.normal.copy_from_slice(other.normal);
        self.prescribed.copy_from_slice(other.prescribed);
        self.flag.copy_from_slice(other.flag);
        self.rot.copy_from_slice(other.rot);
        self.quat.copy_from_slice(other.quat);
        self.ghat.copy_from_slice(other.ghat);
        self.lam.copy_from_slice(other.lam);
        self.alp.copy_from_slice(other.alp);
        self.probe = other.probe;
        self.probe_cmd = other.probe_cmd;
        self.f_cmd_norm = other.f_cmd_norm;
        self.reaction = other.reaction;
        self.reaction_norm = other.reaction_norm;
        self.tick_count = other.tick_count;
        self.precond_valid = false;
        Ok(())
    }

    /// Sets the displacements directly (3 per node; fixed nodes are kept at zero) and refreshes
    /// rotations, strains and blended parameters for that state without solving. For tests,
    /// replays and blending checks.
    pub fn set_displacements(&mut self, u: &[f32]) -> Result<(), RuntimeError> {
        if u.len() != 3 * self.n {
            return Err(RuntimeError::ModelShape {
                what: "displacements",
                expected: 3 * self.n,
                found: u.len(),
            });
        }
        if !u.iter().all(|v| v.is_finite()) {
            return Err(RuntimeError::NonFiniteInput {
                what: "displacements",
            });
        }
        self.u.copy_from_slice(u);
        for i in 0..self.n {
            if self.flag[i] == FIXED {
                self.u[3 * i..3 * i + 3].copy_from_slice(&[0.0; 3]);
            }
        }
        self.refresh_state();
        Ok(())
    }

    /// The element's current rest-frame strain (6-vector, engineering shear), available when the
    /// model blends in strain space.
    pub fn element_strain(&self, e: usize) -> Option<[f32; 6]> {
        let s = self.strain.get(6 * e..6 * e + 6)?;
        let mut o = [0.0; 6];
        o.copy_from_slice(s);
        Some(o)
    }

    /// Number of nodes.
    pub fn node_count(&self) -> usize {
        self.n
    }
    /// Number of elements.
    pub fn element_count(&self) -> usize {
        self.t
    }
    /// Displacements u = x − x₀ (3 per node, m).
    pub fn displacements(&self) -> &[f32] {
        self.u
    }
    /// Rest positions x₀ (3 per node, m).
    pub fn rest_positions(&self) -> &[f32] {
        self.x0
    }
    /// Current (λ_e, α_e) of an element (after blending).
    pub fn element_parameters(&self, e: usize) -> Option<(f32, f32)> {
        Some((*self.lam.get(e)?, *self.alp.get(e)?))
    }
    /// Current rotation R_e (row-major) of an element.
    pub fn element_rotation(&self, e: usize) -> Option<[f32; 9]> {
        if e >= self.t {
            return None;
        }
        Some(core::array::from_fn(|k| self.rot[blk(e, k, 9)]))
    }
    /// Gmsh tag of a node (or its index + 1 if the model carries no tags).
    pub fn node_tag(&self, i: usize) -> u32 {
        self.record.node_tags.get(i).unwrap_or(i as u32 + 1)
    }
    /// Force the object exerts on the probe after the last tick (N).
    pub fn reaction(&self) -> [f32; 3] {
        self.reaction
    }
    /// Whether `node` is fixed.
    pub fn is_fixed(&self, node: usize) -> bool {
        self.flag.get(node) == Some(&FIXED)
    }
    /// Lumped surface area of a node (m²; zero for interior nodes).
    pub fn lumped_area(&self, node: usize) -> f32 {
        self.area.get(node).copied().unwrap_or(0.0)
    }
    /// The configuration.
    pub fn config(&self) -> &RuntimeConfig {
        &self.config
    }
    /// Changes the solver budget and tolerance (e.g. a tighter solve for offline use).
    pub fn set_budget(&mut self, max_iterations: u32, tolerance: f32) {
        self.config.max_iterations = max_iterations;
        self.config.tolerance = tolerance;
    }
    /// Changes the incremental-loading steps.
    pub fn set_load_steps(&mut self, load_step: f32, probe_step: f32) {
        self.config.load_step = load_step;
        self.config.probe_step = probe_step;
    }
    /// Storage the runtime holds, in bytes (f32 + u32 pools plus the struct itself).
    pub fn footprint_bytes(&self) -> usize {
        StorageRequirement::for_model(&self.record, &self.config).bytes()
            + core::mem::size_of::<Self>()
    }
}

pub(crate) fn norm(v: &[f32]) -> f32 {
    libm::sqrt(crate::kernel::norm2_lanes(v)) as f32
}
