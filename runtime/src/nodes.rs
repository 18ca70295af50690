//! The node state: rest positions, displacements and the forces on the nodes.
//!
//! This room changes when what the runtime knows per node changes: where a node rests, where it
//! is, which load is commanded and applied there, and the residual force the last solve left on
//! it (whose probe-held part is the reaction the haptic device renders).

use crate::contact_rule::lumped_surface_areas;
use crate::error::RuntimeError;
use crate::pcg::norm;
use crate::storage::{Carver, Dims, RoomLayout};
use palpate_protocol::model::ModelRecord;

/// Per-node arrays (3 values per node unless noted).
pub(crate) struct NodeState<'a> {
    /// Nodes n.
    pub n: usize,
    /// Rest positions x₀.
    pub x0: &'a mut [f32],
    /// Displacements u = x − x₀.
    pub u: &'a mut [f32],
    /// u at the last residual pass over the elements (a quiet tick at the same u, loads and
    /// settled rotations reuses that pass's residual, [`crate::tick`]).
    pub u_pass: &'a mut [f32],
    /// u at the start of the tick: a rejected solve returns to it.
    pub u_good: &'a mut [f32],
    /// Commanded load.
    pub f_cmd: &'a mut [f32],
    /// Applied load f_k, moving toward `f_cmd` by incremental loading (seed 000 §6.1).
    pub f_app: &'a mut [f32],
    /// Unfiltered residual f_app − f_int(x): at probe-held nodes, the reaction (−contact force).
    pub r_full: &'a mut [f32],
    /// This tick's increment δ (the PCG iterate).
    pub delta: &'a mut [f32],
    /// The previous tick's increment δ, the predictor's direction (see [`crate::pcg::predict`]).
    pub delta_prev: &'a mut [f32],
    /// r_full at the start of the last solve (the line search's slope at the step's start).
    pub r_start: &'a mut [f32],
    /// Lumped surface area A_i of the contact rule (1 per node; zero for interior nodes).
    pub area: &'a mut [f32],
    /// ‖f_cmd‖.
    pub f_cmd_norm: f32,
}

impl<'a> NodeState<'a> {
    /// The room's arrays, in carving order (see [`crate::storage::Layout`]).
    pub(crate) const fn layout(d: &Dims) -> RoomLayout<11, 0> {
        let v = 3 * d.nodes;
        RoomLayout {
            f32s: [v, v, v, v, v, v, v, v, v, v, d.nodes],
            u32s: [],
        }
    }

    /// Cuts the room from the pools (zeroed).
    pub(crate) fn carve(
        layout: RoomLayout<11, 0>,
        n: usize,
        f: &mut Carver<'a, f32>,
        u32s: &mut Carver<'a, u32>,
    ) -> Result<Self, RuntimeError> {
        let ([x0, u, u_pass, u_good, f_cmd, f_app, r_full, delta, delta_prev, r_start, area], []) =
            layout.carve(f, u32s)?;
        Ok(Self {
            n,
            x0,
            u,
            u_pass,
            u_good,
            f_cmd,
            f_app,
            r_full,
            delta,
            delta_prev,
            r_start,
            area,
            f_cmd_norm: 0.0,
        })
    }

    /// Copies the model's rest positions (all finite).
    pub(crate) fn load_rest(&mut self, rec: &ModelRecord<'_>) -> Result<(), RuntimeError> {
        for (i, v) in rec.rest_positions.iter().enumerate() {
            if !v.is_finite() {
                return Err(RuntimeError::NonFiniteInput {
                    what: "rest position",
                });
            }
            self.x0[i] = v;
        }
        Ok(())
    }

    /// Checks the surface triangles' indices and lumps their areas onto their nodes (the
    /// contact rule's A_i), one triangle at a time so no n-sized f64 buffer is needed.
    pub(crate) fn load_areas(&mut self, rec: &ModelRecord<'_>) -> Result<(), RuntimeError> {
        let tri_count = rec.surface_triangles.len() / 3;
        for (i, idx) in rec.surface_triangles.iter().enumerate() {
            RuntimeError::check_index("surface_triangles", i, idx, self.n)?;
        }
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
        Ok(())
    }

    /// Zero displacement, loads and increments (the rest state).
    pub(crate) fn reset(&mut self) {
        for v in [
            &mut *self.u,
            &mut *self.u_good,
            &mut *self.f_cmd,
            &mut *self.f_app,
            &mut *self.delta,
            &mut *self.delta_prev,
            &mut *self.r_start,
        ] {
            v.iter_mut().for_each(|x| *x = 0.0);
        }
        self.f_cmd_norm = 0.0;
    }

    /// Removes every commanded load.
    pub(crate) fn clear_loads(&mut self) {
        self.f_cmd.iter_mut().for_each(|x| *x = 0.0);
        self.f_cmd_norm = 0.0;
    }

    /// ‖f_cmd − f_app‖: how much of the commanded load is not applied yet (N).
    pub(crate) fn load_gap(&self) -> f32 {
        let mut diff2 = 0.0f64;
        for (a, c) in self.f_app.iter().zip(self.f_cmd.iter()) {
            diff2 += ((c - a) as f64) * ((c - a) as f64);
        }
        libm::sqrt(diff2) as f32
    }

    /// One load increment (seed 000 §6.1, ∆f): moves the applied load toward the commanded one
    /// by `step` newtons (in ‖·‖₂ over all nodes; all of it when the gap is smaller, or `step` is
    /// not finite). Returns the change's product with `delta_prev`, the last step (the line
    /// search needs the energy slope along that step at the load it was taken under).
    pub(crate) fn advance_load(&mut self, step: f32) -> f32 {
        let diff = self.load_gap();
        let s = if diff <= step || !step.is_finite() || diff <= 0.0 {
            1.0
        } else {
            step / diff
        };
        let mut along = 0.0f32;
        for ((a, c), d) in self
            .f_app
            .iter_mut()
            .zip(self.f_cmd.iter())
            .zip(self.delta_prev.iter())
        {
            let df = if s == 1.0 { c - *a } else { s * (c - *a) };
            *a = if s == 1.0 { *c } else { *a + df };
            along += df * d;
        }
        along
    }

    /// ‖f_app‖ / ‖f_cmd‖ (1 when nothing is commanded).
    pub(crate) fn load_fraction(&self) -> f32 {
        if self.f_cmd_norm > 0.0 {
            norm(self.f_app) / self.f_cmd_norm
        } else {
            1.0
        }
    }

    /// Adds `force` to the commanded load of `node`.
    pub(crate) fn add_nodal_force(
        &mut self,
        node: usize,
        force: [f32; 3],
    ) -> Result<(), RuntimeError> {
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

    /// Copies the simulation state of another runtime's nodes (same node count).
    pub(crate) fn copy_state_from(&mut self, other: &NodeState<'_>) {
        self.u.copy_from_slice(other.u);
        self.delta_prev.copy_from_slice(other.delta_prev);
        self.f_cmd.copy_from_slice(other.f_cmd);
        self.f_app.copy_from_slice(other.f_app);
        self.r_full.copy_from_slice(other.r_full);
        self.f_cmd_norm = other.f_cmd_norm;
    }
}
