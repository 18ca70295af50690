//! The contact set: which nodes are constrained and how — fixed, held by the probe (with the
//! probe's normal and the position it prescribes) or free — the probe itself and its reaction.
//!
//! This room changes when the contact model changes. Constraints are filters on the CG vectors
//! (modified PCG, Baraff & Witkin 1998): fixed nodes have no free direction; probe-held nodes keep
//! their two tangential directions (frictionless). The filter S is this room's
//! [`Projection`]. Fixed and probe-held nodes share one flag per node because S treats both.

use crate::error::RuntimeError;
use crate::nodes::NodeState;
use crate::pcg::Projection;
use crate::storage::{Carver, Dims, RoomLayout};
use palpate_protocol::model::ModelRecord;

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

/// The constrained nodes and the probe.
pub(crate) struct ContactSet<'a> {
    /// [`FREE`], [`FIXED`] or [`PROBED`], one per node.
    pub flag: &'a mut [u32],
    /// Probe normal at held nodes (3 per node).
    pub normal: &'a mut [f32],
    /// Prescribed normal position n·x at held nodes (1 per node).
    pub prescribed: &'a mut [f32],
    /// The probe where it is now (incremental loading moves it toward `probe_cmd`).
    pub probe: Probe,
    /// The commanded probe.
    pub probe_cmd: Probe,
    /// Force the object exerts on the probe after the last tick (N).
    pub reaction: [f32; 3],
    /// ‖reaction‖, part of the PCG's residual scale.
    pub reaction_norm: f32,
    /// Contact-rule weight of each node for a unit force at the last contact (lumped: the
    /// node's share; consistent: its raw integral ∫N_i dA, scaled by `weight_scale`).
    pub weight: &'a mut [f32],
    /// 1/Σ of the consistent rule's integrals (1 for the lumped rule).
    pub weight_scale: f32,
    /// The (point, radius) the weights were computed for: a haptic loop commands a new force at
    /// the same point every sample, and only the magnitude changes — the geometric search over
    /// nodes and triangles is done once per contact point, not once per sample.
    pub weights_for: Option<([f32; 3], f32)>,
}

impl<'a> ContactSet<'a> {
    /// The room's arrays, in carving order (see [`crate::storage::Layout`]).
    pub(crate) const fn layout(d: &Dims) -> RoomLayout<3, 1> {
        RoomLayout {
            f32s: [3 * d.nodes, d.nodes, d.nodes],
            u32s: [d.nodes],
        }
    }

    /// Cuts the room from the pools (zeroed: every node free).
    pub(crate) fn carve(
        layout: RoomLayout<3, 1>,
        f: &mut Carver<'a, f32>,
        u: &mut Carver<'a, u32>,
    ) -> Result<Self, RuntimeError> {
        let ([normal, prescribed, weight], [flag]) = layout.carve(f, u)?;
        Ok(Self {
            flag,
            normal,
            prescribed,
            probe: Probe::None,
            probe_cmd: Probe::None,
            reaction: [0.0; 3],
            reaction_norm: 0.0,
            weight,
            weight_scale: 1.0,
            weights_for: None,
        })
    }

    /// Marks the model's fixed nodes (indices checked against the `n` nodes).
    pub(crate) fn load_fixed(
        &mut self,
        rec: &ModelRecord<'_>,
        n: usize,
    ) -> Result<(), RuntimeError> {
        for (i, idx) in rec.fixed_nodes.iter().enumerate() {
            RuntimeError::check_index("fixed_nodes", i, idx, n)?;
            self.flag[idx as usize] = FIXED;
        }
        Ok(())
    }

    /// Whether `node` is fixed.
    pub(crate) fn is_fixed(&self, node: usize) -> bool {
        self.flag.get(node) == Some(&FIXED)
    }

    /// Releases every held node and removes the probe; fixed nodes stay fixed.
    pub(crate) fn reset(&mut self) {
        for f in self.flag.iter_mut() {
            if *f == PROBED {
                *f = FREE;
            }
        }
        self.probe = Probe::None;
        self.probe_cmd = Probe::None;
        self.reaction = [0.0; 3];
        self.reaction_norm = 0.0;
    }

    /// Commands the probe (validated). A probe of a new kind (or the first one) starts at its
    /// command; otherwise incremental loading moves it there.
    pub(crate) fn set_probe(&mut self, probe: Probe) -> Result<(), RuntimeError> {
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

    /// Incremental loading of the probe: moves it toward its command by at most `step` metres.
    pub(crate) fn advance_probe(&mut self, step: f32) {
        self.probe = match (self.probe, self.probe_cmd) {
            (_, Probe::None) => Probe::None,
            (Probe::Sphere { center: c0, .. }, Probe::Sphere { center: c1, radius }) => {
                Probe::Sphere {
                    center: step_toward(c0, c1, step),
                    radius,
                }
            }
            (
                Probe::Flat { center: c0, .. },
                Probe::Flat {
                    center: c1,
                    axis,
                    radius,
                },
            ) => Probe::Flat {
                center: step_toward(c0, c1, step),
                axis,
                radius,
            },
            (_, cmd) => cmd,
        };
    }

    /// Updates which surface nodes the probe holds and their targets from the current positions
    /// and last tick's residual (a held node is released when the probe would have to pull it);
    /// returns the count.
    pub(crate) fn update(&mut self, nodes: &NodeState<'_>) -> u32 {
        let mut count = 0;
        for i in 0..nodes.n {
            if self.flag[i] == FIXED || nodes.area[i] <= 0.0 {
                continue;
            }
            let x = [
                nodes.x0[3 * i] + nodes.u[3 * i],
                nodes.x0[3 * i + 1] + nodes.u[3 * i + 1],
                nodes.x0[3 * i + 2] + nodes.u[3 * i + 2],
            ];
            let held = self.flag[i] == PROBED;
            // Contact force on the node c_i = −r_full_i; the probe can only push (c·n ≥ 0).
            let pushing = if held {
                let n = [
                    self.normal[3 * i],
                    self.normal[3 * i + 1],
                    self.normal[3 * i + 2],
                ];
                -(nodes.r_full[3 * i] * n[0]
                    + nodes.r_full[3 * i + 1] * n[1]
                    + nodes.r_full[3 * i + 2] * n[2])
                    >= 0.0
            } else {
                true
            };
            let target = match self.probe {
                Probe::None => None,
                Probe::Sphere { center, radius } => {
                    let d = [x[0] - center[0], x[1] - center[1], x[2] - center[2]];
                    let dist = libm::sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
                    if (dist < radius || held) && dist > 1e-12 {
                        let n = [d[0] / dist, d[1] / dist, d[2] / dist];
                        let inside = dist < radius;
                        Some((
                            n,
                            n[0] * center[0] + n[1] * center[1] + n[2] * center[2] + radius,
                            inside,
                        ))
                    } else {
                        None
                    }
                }
                Probe::Flat {
                    center,
                    axis,
                    radius,
                } => {
                    let d = [x[0] - center[0], x[1] - center[1], x[2] - center[2]];
                    let along = d[0] * axis[0] + d[1] * axis[1] + d[2] * axis[2];
                    let radial = [
                        d[0] - along * axis[0],
                        d[1] - along * axis[1],
                        d[2] - along * axis[2],
                    ];
                    let rr = libm::sqrtf(
                        radial[0] * radial[0] + radial[1] * radial[1] + radial[2] * radial[2],
                    );
                    if rr <= radius && (along < 0.0 || held) {
                        let plane = axis[0] * center[0] + axis[1] * center[1] + axis[2] * center[2];
                        Some((axis, plane, along < 0.0))
                    } else {
                        None
                    }
                }
            };
            match target {
                Some((n, plane, inside)) if (!held && inside) || (held && pushing) => {
                    self.flag[i] = PROBED;
                    self.normal[3 * i..3 * i + 3].copy_from_slice(&n);
                    self.prescribed[i] = plane;
                    count += 1;
                }
                _ => {
                    if held {
                        self.flag[i] = FREE;
                    }
                }
            }
        }
        count
    }

    /// Moves probe-held nodes onto the probe (their prescribed normal position).
    pub(crate) fn apply_prescribed(&self, x0: &[f32], u: &mut [f32]) {
        for (i, fl) in self.flag.iter().enumerate() {
            if *fl == PROBED {
                let n = [
                    self.normal[3 * i],
                    self.normal[3 * i + 1],
                    self.normal[3 * i + 2],
                ];
                let x = [
                    x0[3 * i] + u[3 * i],
                    x0[3 * i + 1] + u[3 * i + 1],
                    x0[3 * i + 2] + u[3 * i + 2],
                ];
                let gap = self.prescribed[i] - (n[0] * x[0] + n[1] * x[1] + n[2] * x[2]);
                for (u, nk) in u[3 * i..3 * i + 3].iter_mut().zip(n) {
                    *u += gap * nk;
                }
            }
        }
    }

    /// The force on the probe: Σ over held nodes of r_full (= −contact force on the node).
    /// Stores it (and its norm) and returns it.
    pub(crate) fn update_reaction(&mut self, r_full: &[f32]) -> [f32; 3] {
        let mut reaction = [0.0f32; 3];
        for (fl, r) in self.flag.iter().zip(r_full.chunks_exact(3)) {
            if *fl == PROBED {
                for (rk, f) in reaction.iter_mut().zip(r) {
                    *rk += f;
                }
            }
        }
        self.reaction = reaction;
        self.reaction_norm = libm::sqrtf(
            reaction[0] * reaction[0] + reaction[1] * reaction[1] + reaction[2] * reaction[2],
        );
        reaction
    }

    /// Copies another runtime's contact state (same node count).
    pub(crate) fn copy_state_from(&mut self, other: &ContactSet<'_>) {
        self.normal.copy_from_slice(other.normal);
        self.prescribed.copy_from_slice(other.prescribed);
        self.flag.copy_from_slice(other.flag);
        self.probe = other.probe;
        self.probe_cmd = other.probe_cmd;
        self.reaction = other.reaction;
        self.reaction_norm = other.reaction_norm;
    }
}

impl Projection for ContactSet<'_> {
    /// The constraint filter S at node `i`: zero if fixed, the normal component removed if held.
    #[inline(always)]
    fn project_node(&self, i: usize, mut v: [f32; 3]) -> [f32; 3] {
        match self.flag.get(i).copied() {
            Some(FIXED) => [0.0; 3],
            Some(PROBED) => {
                if let Some(n) = self.normal.get(3 * i..3 * i + 3) {
                    let d = v[0] * n[0] + v[1] * n[1] + v[2] * n[2];
                    for (vk, nk) in v.iter_mut().zip(n) {
                        *vk -= d * nk;
                    }
                }
                v
            }
            _ => v,
        }
    }

    /// v ← S v over all nodes.
    fn project(&self, v: &mut [f32]) {
        for (fl, (vi, n)) in self
            .flag
            .iter()
            .zip(v.chunks_exact_mut(3).zip(self.normal.chunks_exact(3)))
        {
            match *fl {
                FIXED => {
                    vi[0] = 0.0;
                    vi[1] = 0.0;
                    vi[2] = 0.0;
                }
                PROBED => {
                    let d = vi[0] * n[0] + vi[1] * n[1] + vi[2] * n[2];
                    for k in 0..3 {
                        vi[k] -= d * n[k];
                    }
                }
                _ => {}
            }
        }
    }
}

fn step_toward(from: [f32; 3], to: [f32; 3], max_step: f32) -> [f32; 3] {
    let d = [to[0] - from[0], to[1] - from[1], to[2] - from[2]];
    let len = libm::sqrtf(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    if len <= max_step || !max_step.is_finite() {
        to
    } else {
        let s = max_step / len;
        [from[0] + s * d[0], from[1] + s * d[1], from[2] + s * d[2]]
    }
}
