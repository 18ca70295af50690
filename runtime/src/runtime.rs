//! The runtime object: rooms of fixed arrays carved from caller storage ([`crate::storage`]),
//! built once from a model, then driven tick by tick (see [`crate::tick`]) without allocating.
//!
//! The rooms, each in its own module with one reason to change: the node state
//! ([`NodeState`]), the contact set ([`ContactSet`]), the element state ([`ElementState`]), the
//! element-force buffer of K' ([`ElementForces`]), the preconditioner ([`TwoLevel`]) and the PCG's
//! vectors ([`PcgWork`]). This module builds them and keeps the public API.

use crate::anticipate::Anticipation;
use crate::blend::blend_parameters;
use crate::config::RuntimeConfig;
use crate::contact_rule::{contact_integrals, contact_weights_by, ContactRule, ContactRuleError};
use crate::contact_set::{ContactSet, Probe, FIXED};
use crate::element::PACKED_LEN;
use crate::element_state::ElementState;
use crate::error::RuntimeError;
use crate::nodes::NodeState;
use crate::pcg::{norm, PcgWork};
use crate::stiffness::{internal_forces, ElementForces};
use crate::storage::{Carver, Dims, Layout, StorageRequirement};
use crate::two_level::TwoLevel;
use palpate_protocol::model::{ModelRecord, ParameterLayout};

/// The fixed-memory warped-stiffness simulator.
pub struct Runtime<'a> {
    pub(crate) record: ModelRecord<'a>,
    pub(crate) config: RuntimeConfig,
    pub(crate) nodes: NodeState<'a>,
    pub(crate) contact: ContactSet<'a>,
    pub(crate) work: PcgWork<'a>,
    pub(crate) elements: ElementState<'a>,
    pub(crate) forces: ElementForces<'a>,
    pub(crate) precond: TwoLevel<'a>,
    pub(crate) anticipation: Anticipation<'a>,
    pub(crate) tick_count: u64,
    /// The energy slope s(0) at the start of the last step, while the line search has yet to
    /// check that step (see [`crate::tick`]).
    pub(crate) pending_slope: Option<f32>,
    /// Whether the last tick ran PCG iterations (a preconditioner refresh that is due waits for
    /// a tick after one that did not, [`crate::tick`]).
    pub(crate) last_solved: bool,
    /// `r_full` is the residual of the last pass over the elements, made at `u_pass` and the
    /// applied load of now, and that pass turned no rotation by more than the rotation
    /// tolerance: a pass at the same state would change the residual by less than the solve
    /// can see, so a tick there reuses it ([`crate::tick`]).
    pub(crate) pass_settled: bool,
    /// Residual passes over the elements this tick ([`crate::TickReport::passes`]).
    pub(crate) passes: u32,
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
        // The one layout sizes the pools (checked up front) and is carved room by room.
        let dims = Dims::of(&record, &config);
        let layout = Layout::of(&dims);
        let mut fc = Carver::new(f32_storage, layout.f32s(), "f32")?;
        let mut uc = Carver::new(u32_storage, layout.u32s(), "u32")?;
        let Layout {
            nodes,
            contact,
            work,
            elements,
            forces,
            precond,
            anticipation,
        } = layout;
        let mut rt = Runtime {
            record,
            config,
            nodes: NodeState::carve(nodes, n, &mut fc, &mut uc)?,
            contact: ContactSet::carve(contact, &mut fc, &mut uc)?,
            work: PcgWork::carve(work, &mut fc, &mut uc)?,
            precond: TwoLevel::carve(precond, &dims, &mut fc, &mut uc)?,
            elements: ElementState::carve(elements, &dims, &mut fc, &mut uc)?,
            forces: ElementForces::carve(forces, &mut fc, &mut uc)?,
            anticipation: Anticipation::carve(anticipation, &mut fc, &mut uc)?,
            tick_count: 0,
            pending_slope: None,
            last_solved: false,
            pass_settled: false,
            passes: 0,
        };
        rt.load(&dims)?;
        rt.reset();
        Ok(rt)
    }

    /// Fills the rooms from the model, in the order its checks report errors: rest positions,
    /// connectivity, fixed nodes, surface, elements (geometry and C_e/D_e), parameters, node
    /// coverage; then the incidences and the coarse space.
    fn load(&mut self, dims: &Dims) -> Result<(), RuntimeError> {
        let rec = self.record;
        let n = self.nodes.n;
        let t = self.elements.t;
        self.nodes.load_rest(&rec)?;
        self.elements.load_tets(&rec, n)?;
        self.contact.load_fixed(&rec, n)?;
        self.nodes.load_areas(&rec)?;
        self.elements.load_geometry(&rec, self.nodes.x0)?;
        self.elements.load_parameters(&rec)?;
        // Every free node must belong to a tetrahedron (else K' is singular). The protocol's check
        // needs one bit per node of scratch: the coarse aggregate array (n u32, filled below) is
        // free until the coarse space is built, and serves as the incidence sort's cursor too.
        palpate_protocol::model::validate_node_coverage(
            &rec,
            bytemuck::cast_slice_mut(&mut *self.precond.coarse.agg),
        )
        .map_err(RuntimeError::InvalidModel)?;
        self.forces
            .build(&self.elements, n, &mut *self.precond.coarse.agg);
        let contact = &self.contact;
        let el = &self.elements;
        self.precond.coarse.build(
            dims.aggregates,
            self.nodes.x0,
            |i| contact.is_fixed(i),
            &el.tets[..4 * t],
            |e| el.element_grad(e),
            &el.vol[..t],
            el.lam,
            el.alp,
        );
        Ok(())
    }

    /// Returns the object to rest: zero displacement and loads, identity rotations, no probe.
    pub fn reset(&mut self) {
        self.nodes.reset();
        self.elements.reset_rotations();
        self.contact.reset();
        self.anticipation.reset();
        self.tick_count = 0;
        self.pending_slope = None;
        self.last_solved = false;
        self.pass_settled = false;
        self.precond.valid = false;
    }

    /// Removes every commanded load and the probe (the object relaxes over the next ticks).
    pub fn clear_loads(&mut self) {
        self.nodes.clear_loads();
        self.contact.probe_cmd = Probe::None;
        self.anticipation.forget();
        self.anticipation.force = [0.0; 3];
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
        let n = self.nodes.n;
        let key = (point, radius);
        if self.contact.weights_for != Some(key) {
            let before = self.contact.weights_for.take();
            self.contact.weight_scale = self.compute_contact_weights(point, radius)?;
            self.contact.weights_for = Some(key);
            self.observe_contact_set(before.map(|(p, _)| p));
        }
        self.anticipation.force = force;
        let (weight, scale) = (&*self.contact.weight, self.contact.weight_scale);
        let f_cmd = &mut *self.nodes.f_cmd;
        let mut count = 0;
        for i in 0..n {
            let w = weight[i];
            for k in 0..3 {
                f_cmd[3 * i + k] = (w * force[k]) * scale;
            }
            if w != 0.0 && force.iter().any(|v| *v != 0.0) {
                count += 1;
            }
        }
        self.nodes.f_cmd_norm = norm(f_cmd);
        Ok(count)
    }

    /// What the anticipation of rim crossings ([`crate::anticipate`]) needs from a new contact
    /// point: the previous one (the probe's step) and whether the loaded set changed.
    fn observe_contact_set(&mut self, previous: Option<[f32; 3]>) {
        if !self.anticipation.enabled() {
            return;
        }
        let signature = crate::anticipate::set_signature(
            self.contact
                .weight
                .iter()
                .enumerate()
                .filter(|(_, w)| **w != 0.0)
                .map(|(i, _)| i),
        );
        if signature != self.anticipation.set_signature {
            self.anticipation.set_signature = signature;
            self.anticipation.set_changed = true;
        }
        self.anticipation.previous_point = previous;
    }

    /// The contact rule's weights for a unit force at `point` within `radius` into
    /// `contact.weight`; returns the scale (1/Σ for the consistent rule, 1 for the lumped one).
    fn compute_contact_weights(
        &mut self,
        point: [f32; 3],
        radius: f32,
    ) -> Result<f32, RuntimeError> {
        let n = self.nodes.n;
        let x0 = &*self.nodes.x0;
        let flag = &*self.contact.flag;
        let area = &*self.nodes.area;
        let tris = self.record.surface_triangles;
        let weight = &mut *self.contact.weight;
        weight.iter_mut().for_each(|x| *x = 0.0);
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
        match self.config.contact_rule {
            ContactRule::Lumped => {
                contact_weights_by(
                    c,
                    radius as f64,
                    n,
                    pos,
                    |i| area[i] as f64,
                    |i| flag[i] == FIXED,
                    |i, w| weight[i] = w as f32,
                )
                .map_err(to_runtime)?;
                Ok(1.0)
            }
            ContactRule::Consistent => {
                // One pass accumulating the raw integrals ∫ N_i dA, then one scaling by 1/Σ.
                let (total, _) = contact_integrals(
                    c,
                    radius as f64,
                    n,
                    pos,
                    tris.len() / 3,
                    |k| [0, 1, 2].map(|j| tris.get(3 * k + j).map_or(usize::MAX, |v| v as usize)),
                    |i| flag[i] == FIXED,
                    |i, l| weight[i] += l as f32,
                )
                .map_err(to_runtime)?;
                Ok((1.0 / total) as f32)
            }
        }
    }

    /// The commanded force on `node` (N), None out of range.
    pub fn commanded_force(&self, node: usize) -> Option<[f32; 3]> {
        let f = self.nodes.f_cmd.get(3 * node..3 * node + 3)?;
        Some([f[0], f[1], f[2]])
    }

    /// Commands an explicit nodal force (N) on top of the current commanded load.
    pub fn add_nodal_force(&mut self, node: usize, force: [f32; 3]) -> Result<(), RuntimeError> {
        self.nodes.add_nodal_force(node, force)
    }

    /// Commands the rigid probe (position-driven contact). Incremental loading moves the probe
    /// toward the command by at most `probe_step` per tick.
    pub fn set_probe(&mut self, probe: Probe) -> Result<(), RuntimeError> {
        self.contact.set_probe(probe)
    }

    /// Copies the simulation state (displacements, rotations, loads, probe, contact set) of
    /// another runtime of the same model, e.g. to compare solver settings on the same tick.
    pub fn copy_state_from(&mut self, other: &Runtime<'_>) -> Result<(), RuntimeError> {
        if other.nodes.n != self.nodes.n || other.elements.t != self.elements.t {
            return Err(RuntimeError::ModelShape {
                what: "state of another model",
                expected: self.nodes.n,
                found: other.nodes.n,
            });
        }
        self.nodes.copy_state_from(&other.nodes);
        self.contact.copy_state_from(&other.contact);
        self.elements.copy_state_from(&other.elements);
        self.tick_count = other.tick_count;
        self.pending_slope = other.pending_slope;
        self.pass_settled = false;
        self.precond.valid = false;
        self.anticipation.reset();
        Ok(())
    }

    /// Sets the displacements directly (3 per node; fixed nodes are kept at zero) and refreshes
    /// rotations, strains and blended parameters for that state without solving. For tests,
    /// replays and blending checks.
    pub fn set_displacements(&mut self, u: &[f32]) -> Result<(), RuntimeError> {
        let n = self.nodes.n;
        if u.len() != 3 * n {
            return Err(RuntimeError::ModelShape {
                what: "displacements",
                expected: 3 * n,
                found: u.len(),
            });
        }
        if !u.iter().all(|v| v.is_finite()) {
            return Err(RuntimeError::NonFiniteInput {
                what: "displacements",
            });
        }
        self.nodes.u.copy_from_slice(u);
        for i in 0..n {
            if self.contact.is_fixed(i) {
                self.nodes.u[3 * i..3 * i + 3].copy_from_slice(&[0.0; 3]);
            }
        }
        self.refresh_state();
        Ok(())
    }

    /// Recomputes rotations, strains and blended parameters for the current displacements.
    pub(crate) fn refresh_state(&mut self) {
        self.precond.valid = false;
        self.pass_settled = false;
        self.pending_slope = None;
        // A jump makes the solves done ahead stale; they restart from their iterates.
        self.anticipation.operator_changed();
        self.anticipation.pending_ready = false;
        // After a jump the last increment predicts nothing.
        self.nodes.delta_prev.iter_mut().for_each(|v| *v = 0.0);
        // A jump to an arbitrary state needs more than the per-tick warm-started iterations.
        self.precond.drift +=
            self.elements
                .update_rotations(self.nodes.u, self.config.warp, 50, 0.0);
        self.precond.drift += blend_parameters(&self.record, &self.nodes, &mut self.elements);
    }

    /// Internal elastic forces f_int(x) = Σ R_e K_e (R_eᵀ x_e − x₀_e) of the current state with the
    /// current rotations (3 per node, N). `out` must hold 3 values per node.
    pub fn internal_forces(&self, out: &mut [f32]) -> Result<(), RuntimeError> {
        if out.len() != 3 * self.nodes.n {
            return Err(RuntimeError::ModelShape {
                what: "internal force buffer",
                expected: 3 * self.nodes.n,
                found: out.len(),
            });
        }
        internal_forces(&self.elements, self.nodes.u, out);
        Ok(())
    }

    /// The element's current rest-frame strain (6-vector, engineering shear), available when the
    /// model blends in strain space.
    pub fn element_strain(&self, e: usize) -> Option<[f32; 6]> {
        let s = self.elements.strain.get(6 * e..6 * e + 6)?;
        let mut o = [0.0; 6];
        o.copy_from_slice(s);
        Some(o)
    }

    /// Number of nodes.
    pub fn node_count(&self) -> usize {
        self.nodes.n
    }
    /// Number of elements.
    pub fn element_count(&self) -> usize {
        self.elements.t
    }
    /// Displacements u = x − x₀ (3 per node, m).
    pub fn displacements(&self) -> &[f32] {
        self.nodes.u
    }
    /// Rest positions x₀ (3 per node, m).
    pub fn rest_positions(&self) -> &[f32] {
        self.nodes.x0
    }
    /// Current (λ_e, α_e) of an element (after blending).
    pub fn element_parameters(&self, e: usize) -> Option<(f32, f32)> {
        Some((*self.elements.lam.get(e)?, *self.elements.alp.get(e)?))
    }
    /// Current rotation R_e (row-major) of an element.
    pub fn element_rotation(&self, e: usize) -> Option<[f32; 9]> {
        if e >= self.elements.t {
            return None;
        }
        Some(self.elements.element_rot(e))
    }
    /// The largest element rotation in force (rad): how far the warped model is from its
    /// linear regime, and what the load-increment rule scales
    /// ([`RuntimeConfig::rotation_increment`]).
    pub fn largest_rotation(&self) -> f32 {
        self.elements.largest_rotation()
    }
    /// Gmsh tag of a node (or its index + 1 if the model carries no tags).
    pub fn node_tag(&self, i: usize) -> u32 {
        self.record.node_tags.get(i).unwrap_or(i as u32 + 1)
    }
    /// Force the object exerts on the probe after the last tick (N).
    pub fn reaction(&self) -> [f32; 3] {
        self.contact.reaction
    }
    /// Whether `node` is fixed.
    pub fn is_fixed(&self, node: usize) -> bool {
        self.contact.is_fixed(node)
    }
    /// Lumped surface area of a node (m²; zero for interior nodes).
    pub fn lumped_area(&self, node: usize) -> f32 {
        self.nodes.area.get(node).copied().unwrap_or(0.0)
    }
    /// The configuration.
    pub fn config(&self) -> &RuntimeConfig {
        &self.config
    }
    /// Changes the solver budget and tolerance (e.g. a tighter solve for offline use).
    pub fn set_budget(&mut self, max_iterations: u32, tolerance: f32) {
        self.config.max_iterations = max_iterations;
        self.config.tolerance = tolerance;
        // The rotations settled to the old tolerance may not be settled to the new one.
        self.pass_settled = false;
    }
    /// Changes the per-tick caps of the load ramp (N) and the probe's travel (m) (see
    /// [`RuntimeConfig::load_step`]).
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
