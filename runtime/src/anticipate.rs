//! A lumped probe's next rim crossings, solved ahead of time in the ticks that have time to spare.
//!
//! Under the lumped contact rule ([`crate::contact_rule`]) the nodal loads of a sliding probe are
//! constant until a node crosses the probe's rim, and then they jump: the force is shared anew
//! over the nodes within the radius. A jump is a point-like load change, the slowest residual a
//! two-level PCG meets (19–21 iterations on the 5k-tet bench block, against 0–1 for the still
//! ticks between crossings), so the crossings set the tick's p99. They are also predictable: the
//! probe moves smoothly, and which nodes cross the rim next — and what the loads become then —
//! follows from its last two contact points and the rest positions the rule reads
//! ([`next_crossings`]).
//!
//! **What is solved ahead.** The room keeps a plan of the next [`PLAN_NODES`] crossing nodes in
//! time order, in up to two groups (the nodes of the earliest contact command, then of the next:
//! nodes symmetric about the probe's path cross in one command or in consecutive ones, as
//! rounding decides; the second only when it comes too soon after the first for the still ticks
//! between them to plan it), and one solve per node, δ_i = K'⁻¹ ∆f_i ([`load_change`]) — relative to
//! the loaded set S of the time for the first group, to S after the first group for the second.
//! Any subset X of a group crossing is covered exactly: the lumped loads of B ⊕ X differ from
//! those of the group's base set B by Σ_{i∈X} (A_{B⊕i} / A_{B⊕X}) ∆f_i (A the sets' lumped
//! areas, [`Plan::combination`]). Two corrections are solved beside them: the tick after
//! a crossing re-extracts the rotations at the moved state (a solve's rotations are frozen), and
//! the residual that leaves is a second jump of its own. Each correction comes from a residual
//! pass at the state the planned steps lead to that extracts the rotations there as that tick
//! will, without keeping them (`KeepRotations` in `runtime/src/stiffness.rs`) — but keeping their
//! rotated gradients: the operator of that tick, which the correction and the second group's
//! solves are made with. The solves are carried a few PCG iterations per still tick
//! ([`crate::RuntimeConfig::anticipation_iterations`]) with the tick's own preconditioner,
//! resumed where they stopped ([`crate::pcg::pcg_iterate`]).
//!
//! **What a crossing tick does with them.** When a contact command changes the loaded set into
//! S ⊕ X for planned nodes X, the tick's predictor starts from the energy-optimal
//! multiples ([`crate::pcg::predict_subspace`], one K' product each) of the planned change's
//! combination and of the correction due from the tick before, instead of the last increment,
//! which is zero after still ticks; the tick after a group's crossing starts from its
//! correction. A crossing that was planned and solved then needs no more iterations than a still
//! tick. A wrong prediction costs those products (the Galerkin coefficients are then small) and
//! the crossing is solved as before: the plan only ever chooses a starting point, never the
//! answer.
//!
//! **What it costs.** The still ticks pay the iterations spent here, only while a planned solve
//! is unfinished; the memory is eleven vectors of 3 values per node and the rotated gradients of
//! one element state (9 per element), carved only when the configuration asks for anticipation
//! under the lumped rule (the consistent rule's loads never jump). A position-driven probe is not
//! anticipated.
//!
//! This room changes when what is anticipated, or how, changes.

use crate::contact_set::Probe;
use crate::pcg::{
    norm, pcg_iterate, pcg_start, CgCarry, CgError, CgParams, LinearOperator, PcgWork,
};
use crate::runtime::Runtime;
use crate::stiffness::{residual_pass, KeepRotations, Stiffness};
use crate::storage::{Carver, Dims, RoomLayout};
use crate::two_level::TwoLevelApply;

/// Crossings further ahead than this many contact commands are not anticipated.
pub const HORIZON: f64 = 10_000.0;

/// Crossing nodes one plan holds (a solve each).
pub const PLAN_NODES: usize = 4;

/// Ticks after a crossing before the still ticks resume (the crossing's own, its correction's,
/// the rotations' last settling), and PCG iterations a group's solves take from nothing (two
/// nodes and a correction, restarts included): a second group further from the first than these
/// allow at the budget is planned after the first has crossed, not before.
const BUSY_AFTER_CROSSING: u32 = 4;
const GROUP_WORK: u32 = 60;

/// A node that crosses the probe's rim.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Crossing {
    /// The node.
    pub node: u32,
    /// Whether it enters the probe's radius (else it leaves).
    pub enters: bool,
    /// Contact commands until it crosses (fractional: the contact point passes the rim between
    /// commands ⌈time⌉ − 1 and ⌈time⌉, counting the next command as 1).
    pub time: f64,
}

/// The next crossings of a probe of `radius` whose contact point moves from `point` by `step`
/// per command along a straight line: the nodes whose membership of the ball ‖x₀ − c‖ ≤ r
/// changes first, in time order (the lowest index first at equal times), into `out`; returns how
/// many (a node counts once, with its first crossing). `x0` holds the rest positions (3 per
/// node); `candidate(i)` says whether node i can carry load (a free surface node), `member(i)`
/// whether it does now. None when the probe stands still or nothing crosses within [`HORIZON`]
/// commands. The same ball test as the rule's, in f64.
pub fn next_crossings(
    point: [f32; 3],
    step: [f32; 3],
    radius: f32,
    x0: &[f32],
    candidate: impl Fn(usize) -> bool,
    member: impl Fn(usize) -> bool,
    out: &mut [Crossing],
) -> usize {
    let v = step.map(|s| s as f64);
    let vv = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    let r = radius as f64;
    if !(vv > 0.0 && vv.is_finite() && r > 0.0 && r.is_finite()) {
        return 0;
    }
    let mut len = 0;
    for i in (0..x0.len() / 3).filter(|&i| candidate(i)) {
        // The root of ‖d − v t‖² = r² (d = x₀ − c) that leaves the ball for a member, enters it
        // for the others.
        let p = &x0[3 * i..3 * i + 3];
        let d = [0, 1, 2].map(|k| p[k] as f64 - point[k] as f64);
        let dv = d[0] * v[0] + d[1] * v[1] + d[2] * v[2];
        let inside = member(i);
        if !inside && dv <= 0.0 {
            // Behind the probe or beside its path: it never enters.
            continue;
        }
        let c = d[0] * d[0] + d[1] * d[1] + d[2] * d[2] - r * r;
        let disc = dv * dv - vv * c;
        if disc.is_nan() || disc < 0.0 {
            continue;
        }
        let root = libm::sqrt(disc);
        let t = if inside {
            (dv + root) / vv
        } else {
            (dv - root) / vv
        };
        if t.is_nan() || t <= 0.0 || t > HORIZON {
            continue;
        }
        // Insertion into the sorted list of the earliest.
        let Some(at) = (0..=len.min(out.len())).find(|&k| k == len || t < out[k].time) else {
            continue;
        };
        if at >= out.len() {
            continue;
        }
        let end = (len + 1).min(out.len());
        for k in (at + 1..end).rev() {
            out[k] = out[k - 1];
        }
        out[at] = Crossing {
            node: i as u32,
            enters: !inside,
            time: t,
        };
        len = end;
    }
    len
}

/// Whether node `i` is loaded once `crossings` have flipped their nodes in the set `member`.
fn member_after(i: usize, member: &impl Fn(usize) -> bool, crossings: &[Crossing]) -> bool {
    crossings.iter().fold(
        member(i),
        |m, c| if c.node as usize == i { c.enters } else { m },
    )
}

/// The lumped rule's load change when `crossings` flip their nodes in the set `member` after
/// `base` flipped theirs, for a force `force`: b_i = F (A_i m′_i / Σ A m′ − A_i m_i / Σ A m), m
/// the set after `base`, m′ after both, `area` the lumped areas (the rule's weights are
/// A_i / Σ A). Written into `b` (3 per node; every other entry zero). Returns false (b zero) if
/// either set is empty.
pub fn load_change(
    base: &[Crossing],
    crossings: &[Crossing],
    force: [f32; 3],
    member: impl Fn(usize) -> bool,
    area: &[f32],
    b: &mut [f32],
) -> bool {
    b.iter_mut().for_each(|v| *v = 0.0);
    let before = |i: usize| member_after(i, &member, base);
    let after = |i: usize| member_after(i, &before, crossings);
    let total = |m: &dyn Fn(usize) -> bool| -> f64 {
        area.iter()
            .enumerate()
            .filter(|&(i, _)| m(i))
            .map(|(_, a)| *a as f64)
            .sum()
    };
    let (total_before, total_after) = (total(&before), total(&after));
    if !(total_before > 0.0 && total_after > 0.0 && total_after.is_finite()) {
        return false;
    }
    for (i, (bi, a)) in b.chunks_exact_mut(3).zip(area).enumerate() {
        let a = *a as f64;
        let was = if before(i) { a / total_before } else { 0.0 };
        let will = if after(i) { a / total_after } else { 0.0 };
        let dw = (will - was) as f32;
        if dw != 0.0 {
            for k in 0..3 {
                bi[k] = force[k] * dw;
            }
        }
    }
    true
}

/// (count, index sum) of a node set: a change of the set changes it unless as many nodes
/// leave as enter with the same index sum.
pub(crate) fn set_signature(members: impl Iterator<Item = usize>) -> (u32, u64) {
    members.fold((0, 0), |(c, s), i| (c + 1, s.wrapping_add(i as u64 + 1)))
}

/// The plan: the next crossing nodes of one loaded set.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plan {
    /// Signature of the set S the crossings are relative to: (count, index sum) of its nodes.
    pub base: (u32, u64),
    /// Σ A_i over S.
    pub base_area: f64,
    /// The crossings (the first `len`), in time order.
    pub nodes: [Crossing; PLAN_NODES],
    /// Their lumped areas.
    pub areas: [f64; PLAN_NODES],
    /// How many.
    pub len: usize,
    /// How many of them cross in the earliest command (the first group); the rest cross in the
    /// next one.
    pub first: usize,
    /// The radius and force the load changes are for.
    pub radius: f32,
    /// See `radius`.
    pub force: [f32; 3],
}

/// One planned solve.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Step {
    /// δ_i of plan node i.
    Delta(usize),
    /// The correction after the first group (0) or after both (1).
    Correction(usize),
}

impl Plan {
    /// The solves in the order the spare iterations go to them: the first group's, its
    /// correction, the second group's, the correction after both. `None` past the last.
    pub(crate) fn step(&self, k: usize) -> Option<Step> {
        let second = self.len > self.first;
        match k {
            k if k < self.first => Some(Step::Delta(k)),
            k if k == self.first => Some(Step::Correction(0)),
            k if k <= self.len => Some(Step::Delta(k - 1)),
            k if k == self.len + 1 && second => Some(Step::Correction(1)),
            _ => None,
        }
    }

    /// Bit mask of the first group, of every node.
    pub(crate) fn groups(&self) -> (u8, u8) {
        ((1u8 << self.first) - 1, (1u8 << self.len) - 1)
    }

    /// The coefficients c_i of the solves for the nodes of `mask` crossing: the first group's
    /// δ_i are relative to S, the second group's to S after the first group, and the crossing
    /// of nodes X of one group is Σ_{i∈X} c_i ∆f_i with c_i = A_{B⊕i} / A_{B⊕X} over that group's
    /// base set B. (Both sides are F Σ_{B⊕…} / A − F Σ_B / A_B; the Σ_B terms agree because
    /// Σ_{i∈X} A_{B⊕i} = (|X| − 1) A_B + A_{B⊕X}.) Exact for crossings of the first group, and
    /// of the second after the whole first.
    pub fn combination(&self, mask: u8) -> [f64; PLAN_NODES] {
        let sign = |i: usize| {
            if self.nodes[i].enters {
                self.areas[i]
            } else {
                -self.areas[i]
            }
        };
        let chosen = |i: usize| mask & (1 << i) != 0;
        let mut c = [0.0; PLAN_NODES];
        let mut base = self.base_area;
        for group in [0..self.first, self.first..self.len] {
            let together = base + group.clone().filter(|&i| chosen(i)).map(sign).sum::<f64>();
            if together > 0.0 {
                for i in group.clone().filter(|&i| chosen(i)) {
                    c[i] = (base + sign(i)) / together;
                }
            }
            base += group.map(sign).sum::<f64>();
        }
        c
    }

    /// The signature of S after the nodes of `mask` flipped.
    fn signature(&self, mask: u8) -> (u32, u64) {
        (0..self.len)
            .filter(|&i| mask & (1 << i) != 0)
            .fold(self.base, |(c, s), i| {
                let x = &self.nodes[i];
                let k = x.node as u64 + 1;
                if x.enters {
                    (c.wrapping_add(1), s.wrapping_add(k))
                } else {
                    (c.wrapping_sub(1), s.wrapping_sub(k))
                }
            })
    }

    /// The crossing nodes of `mask`.
    fn crossings(&self, mask: u8) -> ([Crossing; PLAN_NODES], usize) {
        let mut out = self.nodes;
        let mut k = 0;
        for i in (0..self.len).filter(|&i| mask & (1 << i) != 0) {
            out[k] = self.nodes[i];
            k += 1;
        }
        (out, k)
    }
}

/// What a change of the loaded set is, to the plan.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Fired {
    /// The set did not change.
    Nothing,
    /// The set is the plan's with the nodes of this mask flipped.
    Planned(u8),
    /// The set changed otherwise.
    Unpredicted,
}

/// The anticipated solves and what they were set up for.
pub(crate) struct Anticipation<'a> {
    /// δ_i of the plan's nodes, 3 per node each.
    pub deltas: [&'a mut [f32]; PLAN_NODES],
    /// The corrections after the first group and after both.
    pub corrections: [&'a mut [f32]; 2],
    /// Which of `deltas` have been iterated on (each is then a direction worth trying).
    pub delta_iterated: [bool; PLAN_NODES],
    /// Which of `corrections` have been.
    pub correction_iterated: [bool; 2],
    /// The correction of a crossing that has just happened, for the tick after it.
    pub pending: &'a mut [f32],
    /// The running solve's b − K' x, unfiltered.
    pub r_full: &'a mut [f32],
    /// The running solve's filtered residual, preconditioned residual and direction; `r` also
    /// holds a crossing tick's planned direction.
    pub r: &'a mut [f32],
    /// See `r`.
    pub z: &'a mut [f32],
    /// See `r`.
    pub p: &'a mut [f32],
    /// The rotated gradients R∇φ of the state the last correction's pass extracted them at,
    /// laid out like the elements' own: the operator of the tick after the planned steps.
    pub ghat: &'a mut [f32],
    /// `ghat` is current.
    pub shadow: bool,
    /// The plan.
    pub plan: Option<Plan>,
    /// Which of the plan's nodes have crossed since it was made.
    pub crossed: u8,
    /// The running solve ([`Plan::step`]).
    pub phase: usize,
    /// The running solve's scalars while its vectors are current (`None`: restart it from its
    /// iterate with the residual recomputed).
    pub carry: Option<CgCarry>,
    /// `pending` holds a correction for the coming tick.
    pub pending_ready: bool,
    /// The contact point commanded before the current one (the probe's step is their
    /// difference).
    pub previous_point: Option<[f32; 3]>,
    /// Whether a contact command since the last tick changed which nodes carry the load.
    pub set_changed: bool,
    /// The probe force of the last contact command (N; zero once the loads are cleared).
    pub force: [f32; 3],
    /// [`set_signature`] of the nodes carrying the load now.
    pub set_signature: (u32, u64),
}

impl<'a> Anticipation<'a> {
    /// The room's arrays, in carving order (see [`crate::storage::Layout`]); empty unless
    /// [`Dims::anticipate`].
    pub(crate) const fn layout(d: &Dims) -> RoomLayout<12, 0> {
        let (v, g) = if d.anticipate {
            (3 * d.nodes, 9 * d.padded)
        } else {
            (0, 0)
        };
        RoomLayout {
            f32s: [v, v, v, v, v, v, v, v, v, v, v, g],
            u32s: [],
        }
    }

    /// Cuts the room from the pools (zeroed).
    pub(crate) fn carve(
        layout: RoomLayout<12, 0>,
        f: &mut Carver<'a, f32>,
        u: &mut Carver<'a, u32>,
    ) -> Result<Self, crate::RuntimeError> {
        let ([d0, d1, d2, d3, c0, c1, pending, r_full, r, z, p, ghat], []) = layout.carve(f, u)?;
        Ok(Self {
            deltas: [d0, d1, d2, d3],
            corrections: [c0, c1],
            delta_iterated: [false; PLAN_NODES],
            correction_iterated: [false; 2],
            pending,
            r_full,
            r,
            z,
            p,
            ghat,
            shadow: false,
            plan: None,
            crossed: 0,
            phase: 0,
            carry: None,
            pending_ready: false,
            previous_point: None,
            set_changed: false,
            force: [0.0; 3],
            set_signature: (0, 0),
        })
    }

    /// Whether the room has its vectors (anticipation configured).
    pub(crate) fn enabled(&self) -> bool {
        !self.pending.is_empty()
    }

    /// Drops the plan and its solves (a pending correction stays for the coming tick).
    pub(crate) fn forget(&mut self) {
        self.plan = None;
        self.crossed = 0;
        self.phase = 0;
        self.carry = None;
        self.delta_iterated = [false; PLAN_NODES];
        self.correction_iterated = [false; 2];
        self.shadow = false;
    }

    /// The operator or preconditioner changed: every planned solve is redone from its iterate
    /// (each is still close), the running one restarted with its residual recomputed.
    pub(crate) fn operator_changed(&mut self) {
        self.carry = None;
        self.phase = 0;
        self.shadow = false;
    }

    /// Back to no probe history.
    pub(crate) fn reset(&mut self) {
        self.forget();
        self.pending_ready = false;
        self.previous_point = None;
        self.set_changed = false;
        self.force = [0.0; 3];
        self.set_signature = (0, 0);
    }

    /// What the current node set is to the plan (after a contact command changed it;
    /// [`Fired::Nothing`] if none did). `member(i)`: whether node i carries load now.
    pub(crate) fn fired(&self, member: impl Fn(usize) -> bool) -> Fired {
        if !self.set_changed {
            return Fired::Nothing;
        }
        let Some(plan) = self.plan else {
            return Fired::Unpredicted;
        };
        let mut mask = 0u8;
        for (i, c) in plan.nodes[..plan.len].iter().enumerate() {
            // A node that enters was out of S; it has crossed if it is in now.
            if member(c.node as usize) == c.enters {
                mask |= 1 << i;
            }
        }
        if mask != 0 && mask != self.crossed && plan.signature(mask) == self.set_signature {
            Fired::Planned(mask)
        } else {
            Fired::Unpredicted
        }
    }

    /// The crossing tick's planned direction into `r`: the solves' combination for the change
    /// from the nodes crossed before (`crossed`) to `mask`, Σ (c_i(mask) − c_i(crossed)) δ_i
    /// ([`Plan::combination`]). False when no solve it needs has been iterated on.
    pub(crate) fn planned_direction(&mut self, mask: u8) -> bool {
        let Some(plan) = self.plan else {
            return false;
        };
        let (now, before) = (plan.combination(mask), plan.combination(self.crossed));
        self.r.iter_mut().for_each(|v| *v = 0.0);
        let mut any = false;
        for i in 0..plan.len {
            let c = (now[i] - before[i]) as f32;
            if c != 0.0 && self.delta_iterated[i] {
                any = true;
                for (r, d) in self.r.iter_mut().zip(self.deltas[i].iter()) {
                    *r += c * d;
                }
            }
        }
        any
    }

    /// After a tick a contact command changed the node set in: the planned crossing hands its
    /// group's correction to the coming tick; the plan stays for its other nodes until a still
    /// tick plans anew.
    pub(crate) fn advance(&mut self, fired: Fired) {
        self.set_changed = false;
        self.pending_ready = false;
        self.carry = None;
        let Fired::Planned(mask) = fired else {
            self.forget();
            return;
        };
        let Some(plan) = self.plan else {
            return;
        };
        let (first, all) = plan.groups();
        let correction = if mask == first {
            Some(0)
        } else if mask == all && all != first {
            Some(1)
        } else {
            None
        };
        if let Some(c) = correction.filter(|&c| self.correction_iterated[c]) {
            core::mem::swap(&mut self.pending, &mut self.corrections[c]);
            self.correction_iterated[c] = false;
            self.pending_ready = true;
        }
        self.crossed = mask;
        if mask == all {
            self.forget();
        }
    }
}

impl Runtime<'_> {
    /// Spends up to [`crate::RuntimeConfig::anticipation_iterations`] PCG iterations of a still
    /// tick on the plan: predicts the next crossings from the last two contact points, plans
    /// anew when the loaded set, the radius, the force's direction or the crossings changed (a
    /// node of the old plan keeps its solve as the start of its new one), and goes on with the
    /// solves in [`Plan::step`] order otherwise. A restart's residual counts as an iteration of
    /// the budget. Returns the iterations spent.
    pub(crate) fn anticipate(&mut self) -> u32 {
        let mut budget = self.config.anticipation_iterations;
        let (Some((point, radius)), Some(previous)) =
            (self.contact.weights_for, self.anticipation.previous_point)
        else {
            return 0;
        };
        let force = self.anticipation.force;
        if budget == 0
            || !self.anticipation.enabled()
            || force == [0.0; 3]
            || self.contact.probe != Probe::None
        {
            return 0;
        }
        let step = [0, 1, 2].map(|k| point[k] - previous[k]);
        let (nodes, contact) = (&self.nodes, &self.contact);
        let candidate =
            |i: usize| nodes.area.get(i).is_some_and(|a| *a > 0.0) && !contact.is_fixed(i);
        let member = |i: usize| contact.weight.get(i).is_some_and(|w| *w != 0.0);
        let mut found = [Crossing {
            node: 0,
            enters: false,
            time: 0.0,
        }; PLAN_NODES];
        let len = next_crossings(point, step, radius, nodes.x0, candidate, member, &mut found);
        if len == 0 {
            self.anticipation.forget();
            return 0;
        }
        // Two groups: the nodes of the earliest command, then those of the next one — when that
        // comes too soon after it for the still ticks between them to plan and solve it anew
        // (the ticks a crossing's step keeps busy, then a group's work at this budget).
        let command = |c: &Crossing| libm::ceil(c.time);
        let first = found[..len]
            .iter()
            .take_while(|c| command(c) == command(&found[0]))
            .count();
        let reach = (BUSY_AFTER_CROSSING + GROUP_WORK / budget) as f64;
        let soon = first < len && command(&found[first]) - command(&found[0]) <= reach;
        let len = first
            + found[first..len]
                .iter()
                .take_while(|c| soon && command(c) == command(&found[first]))
                .count();
        let area = |c: &Crossing| nodes.area.get(c.node as usize).map_or(0.0, |a| *a as f64);
        let plan = Plan {
            base: self.anticipation.set_signature,
            // Summed by `adopt`, and only for a plan it takes.
            base_area: 0.0,
            nodes: found,
            areas: found.map(|c| area(&c)),
            len,
            first,
            radius,
            force,
        };
        self.adopt(plan);
        let mut spent = 0;
        while budget > 0 && self.anticipation.plan.is_some() {
            let Some(step) = self
                .anticipation
                .plan
                .and_then(|p| p.step(self.anticipation.phase))
            else {
                break;
            };
            let used = self.anticipate_step(step, budget).max(1);
            spent += used.min(budget);
            budget = budget.saturating_sub(used);
        }
        spent
    }

    /// Makes `plan` the plan: kept as it is when only the times moved; else a new plan (with
    /// its set's lumped area) whose nodes start from the old solves of the same nodes.
    fn adopt(&mut self, mut plan: Plan) {
        let s = &mut self.anticipation;
        let key = |p: &Plan| {
            let mut k = [(u32::MAX, false); PLAN_NODES];
            for (i, c) in p.nodes[..p.len].iter().enumerate() {
                k[i] = (c.node, c.enters);
            }
            (k, p.len, p.first, p.base, p.radius)
        };
        if let Some(old) = s.plan {
            if key(&old) == key(&plan) && parallel(old.force, plan.force) {
                return;
            }
        }
        let old = s
            .plan
            .filter(|o| o.radius == plan.radius && parallel(o.force, plan.force));
        let (weight, area) = (&*self.contact.weight, &*self.nodes.area);
        plan.base_area = weight
            .iter()
            .zip(area)
            .filter(|(w, _)| **w != 0.0)
            .map(|(_, a)| *a as f64)
            .sum();
        let mut kept = [false; PLAN_NODES];
        // at[k]: the slot old node k's solve is in now.
        let mut at: [usize; PLAN_NODES] = core::array::from_fn(|k| k);
        if let Some(old) = old {
            for j in 0..plan.len {
                let n = (plan.nodes[j].node, plan.nodes[j].enters);
                let Some(k) = (0..old.len).find(|&k| {
                    (old.nodes[k].node, old.nodes[k].enters) == n && s.delta_iterated[k]
                }) else {
                    continue;
                };
                let from = at[k];
                if from != j {
                    let (lo, hi) = (from.min(j), from.max(j));
                    let (a, b) = s.deltas.split_at_mut(hi);
                    core::mem::swap(&mut a[lo], &mut b[0]);
                    // The vector that was in slot j moved to `from`.
                    if let Some(m) = at.iter().position(|&p| p == j) {
                        at[m] = from;
                    }
                    at[k] = j;
                }
                kept[j] = true;
            }
        }
        s.forget();
        s.delta_iterated = kept;
        s.plan = Some(plan);
    }

    /// Writes the right-hand side of `step` into `r_full` (the caller subtracts K' x). Returns
    /// false if it cannot be formed (no plan, an empty node set).
    fn anticipated_rhs(&mut self, step: Step) -> bool {
        let s = &mut self.anticipation;
        let contact = &self.contact;
        let member = |i: usize| contact.weight.get(i).is_some_and(|w| *w != 0.0);
        let Some(plan) = s.plan else {
            return false;
        };
        let area = &*self.nodes.area;
        match step {
            Step::Delta(i) => {
                // The second group's crossings are relative to the set after the first's.
                let base = if i < plan.first {
                    &plan.nodes[..0]
                } else {
                    &plan.nodes[..plan.first]
                };
                load_change(base, &[plan.nodes[i]], plan.force, member, area, s.r_full)
            }
            Step::Correction(c) => {
                // What the planned steps leave once the rotations follow them: the loads after
                // the group(s) minus f_int at the moved state, with the rotations extracted
                // there as the following tick will (twice the tick's iterations after both
                // groups, which two ticks would take). The state: u + Σ c_i δ_i, and the first
                // correction after both.
                let (first, all) = plan.groups();
                let mask = if c == 0 { first } else { all };
                let (crossings, k) = plan.crossings(mask);
                let ok = load_change(&[], &crossings[..k], plan.force, member, area, s.p);
                let coefficients = plan.combination(mask);
                let u = &*self.nodes.u;
                for (i, (z, p)) in s.z.iter_mut().zip(s.p.iter_mut()).enumerate() {
                    *p += self.nodes.f_app[i];
                    *z = u[i];
                    for (d, c) in s.deltas[..plan.len].iter().zip(&coefficients) {
                        *z += *c as f32 * d[i];
                    }
                    if c == 1 {
                        *z += s.corrections[0][i];
                    }
                }
                let iterations = self.config.rotation_iterations as usize * (1 + c);
                let rotate = (
                    iterations,
                    self.config.rotation_tolerance * self.config.tolerance,
                );
                // The pass keeps that state's operator (the following tick's) for the solve of
                // this correction and, after the first, of the second group's δ_i.
                s.shadow = self.config.warp;
                residual_pass(
                    &mut self.elements,
                    &mut self.forces,
                    s.z,
                    s.p,
                    s.r_full,
                    Some(rotate).filter(|_| self.config.warp),
                    None,
                    KeepRotations::Gradients(&mut *s.ghat),
                );
                ok
            }
        }
    }

    /// Runs `step`'s solve for at most `budget` iterations (restarting it first if it has no
    /// current vectors) and moves to the next step when it converges. Returns the iterations
    /// used, a restart counting as one.
    fn anticipate_step(&mut self, step: Step, budget: u32) -> u32 {
        let Some(plan) = self.anticipation.plan else {
            return 0;
        };
        // The operator each solve is for: the state's own for the first group's δ_i, else the
        // following tick's, as the last correction's pass extracted it.
        let own = matches!(step, Step::Delta(i) if i < plan.first);
        let scale = norm(self.nodes.f_app).max(self.contact.reaction_norm);
        // The tick's own tolerance: a crossing planned right then needs at most a last iteration.
        let tol = self.config.tolerance * scale + self.config.absolute_tolerance;
        let restart = self.anticipation.carry.is_none();
        if restart && !self.anticipated_rhs(step) {
            self.anticipation.forget();
            return 1;
        }
        let s = &mut self.anticipation;
        let mut k = Stiffness {
            elements: &self.elements,
            forces: &mut self.forces,
            kernel: self.config.kernel,
            rotated: (s.shadow && !own).then_some(&*s.ghat),
        };
        let mut m = TwoLevelApply {
            precond: &mut self.precond,
            x0: self.nodes.x0,
            contact: &self.contact,
        };
        let mut work = PcgWork {
            r: &mut *s.r,
            z: &mut *s.z,
            p: &mut *s.p,
            q: &mut *self.work.q,
        };
        let (x, iterated) = match step {
            Step::Delta(i) => (&mut *s.deltas[i], s.delta_iterated[i]),
            Step::Correction(c) => (&mut *s.corrections[c], s.correction_iterated[c]),
        };
        let mut used = 0;
        if restart {
            // From the iterate: r_full = b − K' x (b written by `anticipated_rhs`).
            used = 1;
            if iterated {
                k.apply(x, work.q);
                for (r, q) in s.r_full.iter_mut().zip(work.q.iter()) {
                    *r -= q;
                }
            } else {
                x.iter_mut().for_each(|v| *v = 0.0);
            }
            let carry = pcg_start(&mut m, &self.contact, s.r_full, &mut work, tol);
            if carry.rnorm <= tol {
                s.phase += 1;
                return used;
            }
            s.carry = Some(carry);
        }
        let Some(mut carry) = s.carry else {
            return used;
        };
        let params = CgParams {
            tolerance: tol,
            max_iterations: budget.saturating_sub(used),
        };
        let outcome = pcg_iterate(
            &mut k,
            &mut m,
            &self.contact,
            x,
            s.r_full,
            &mut work,
            &mut carry,
            params,
        );
        s.carry = Some(carry);
        let iterations = match outcome {
            Ok(info) => info.iterations,
            Err(CgError::NoConvergence { iterations, .. }) => iterations,
            Err(CgError::Breakdown { .. } | CgError::NonFinite { .. }) => {
                s.forget();
                return budget;
            }
        };
        if iterations > 0 {
            match step {
                Step::Delta(i) => s.delta_iterated[i] = true,
                Step::Correction(c) => s.correction_iterated[c] = true,
            }
        }
        if outcome.is_ok() {
            s.carry = None;
            s.phase += 1;
        }
        used + iterations
    }
}

/// Whether two forces point the same way (within 1e-3 rad): the anticipated solves are for the
/// force's direction and scale with its magnitude.
fn parallel(a: [f32; 3], b: [f32; 3]) -> bool {
    let cross = [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ];
    let dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    dot > 0.0 && norm(&cross) <= 1e-3 * norm(&a) * norm(&b)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 9 × 9 grid of nodes 1 cm apart on z = 0, all candidates.
    fn grid() -> std::vec::Vec<f32> {
        let mut x0 = std::vec::Vec::new();
        for j in 0..9 {
            for i in 0..9 {
                x0.extend_from_slice(&[0.01 * i as f32, 0.01 * j as f32, 0.0]);
            }
        }
        x0
    }

    fn members(x0: &[f32], c: [f32; 3], r: f32) -> std::vec::Vec<bool> {
        x0.chunks_exact(3)
            .map(|p| {
                let d: f64 = (0..3)
                    .map(|k| (p[k] as f64 - c[k] as f64).powi(2))
                    .sum::<f64>();
                libm::sqrt(d) <= r as f64
            })
            .collect()
    }

    const NONE: Crossing = Crossing {
        node: 0,
        enters: false,
        time: 0.0,
    };

    #[test]
    fn predicts_the_next_changes_of_the_ball_and_when() {
        // Walk a probe along y = 4 cm in steps of 0.3 mm and compare every prediction with the
        // set changes that then happen, command by command.
        let x0 = grid();
        let r = 0.015f32;
        let step = [0.0003f32, 0.0, 0.0];
        let mut c = [0.0201f32, 0.04, 0.0];
        let mut together = 0;
        for _ in 0..120 {
            let now = members(&x0, c, r);
            let mut out = [NONE; PLAN_NODES];
            let len = next_crossings(c, step, r, &x0, |_| true, |i| now[i], &mut out);
            assert_eq!(len, PLAN_NODES);
            assert!(out.windows(2).all(|w| w[0].time <= w[1].time));
            together += (out[1].time - out[0].time < 1e-9) as usize;
            // Replay the commands: every change up to the last planned one is a planned node
            // crossing at its command, in the direction planned.
            let last = libm::ceil(out[len - 1].time) as usize;
            let mut ahead = c;
            let mut prev = now.clone();
            for k in 1..=last {
                ahead = [ahead[0] + step[0], ahead[1], ahead[2]];
                let then = members(&x0, ahead, r);
                for i in (0..now.len()).filter(|&i| prev[i] != then[i]) {
                    let planned = out[..len].iter().find(|x| x.node as usize == i);
                    let x = planned.expect("an unplanned change before the last planned one");
                    assert_eq!(libm::ceil(x.time) as usize, k, "node {i}");
                    assert_eq!(then[i], x.enters);
                }
                prev = then;
            }
            c = [c[0] + step[0], c[1], c[2]];
        }
        // Rows symmetric about the path cross together.
        assert!(together > 0);
    }

    #[test]
    fn nothing_to_predict_for_a_still_probe() {
        let x0 = grid();
        let c = [0.04f32, 0.04, 0.0];
        let mut out = [NONE; PLAN_NODES];
        assert_eq!(
            next_crossings(c, [0.0; 3], 0.015, &x0, |_| true, |_| false, &mut out),
            0
        );
        let nan = [f32::NAN, 0.0, 0.0];
        assert_eq!(
            next_crossings(c, nan, 0.015, &x0, |_| true, |_| false, &mut out),
            0
        );
        // Moving away from every node: nothing enters.
        let far = [0.5, 0.5, 0.0];
        let away = [0.001, 0.0, 0.0];
        assert_eq!(
            next_crossings(far, away, 0.015, &x0, |_| true, |_| false, &mut out),
            0
        );
    }

    fn crossing(node: u32, enters: bool) -> Crossing {
        Crossing {
            node,
            enters,
            time: 1.0,
        }
    }

    #[test]
    fn the_load_change_is_the_lumped_rule_after_minus_before() {
        // Four nodes of areas 1, 2, 3, 4: nodes 0 and 1 loaded; node 2 enters, node 0 leaves.
        let area = [1.0f32, 2.0, 3.0, 4.0];
        let member = |i: usize| i < 2;
        let f = [0.0f32, 0.0, -0.5];
        let mut b = [0.0f32; 12];
        let pair = [crossing(2, true), crossing(0, false)];
        assert!(load_change(&[], &pair, f, member, &area, &mut b));
        let check = |b: &[f32], before: [f64; 4], after: [f64; 4]| {
            for i in 0..4 {
                let want = (-0.5 * (after[i] - before[i])) as f32;
                assert!((b[3 * i + 2] - want).abs() < 1e-6, "{i}: {}", b[3 * i + 2]);
                assert_eq!(b[3 * i], 0.0);
            }
        };
        check(&b, [1.0 / 3.0, 2.0 / 3.0, 0.0, 0.0], [0.0, 0.4, 0.6, 0.0]);
        // After node 3 entered first: the pair's change from {0, 1, 3}.
        assert!(load_change(
            &[crossing(3, true)],
            &pair,
            f,
            member,
            &area,
            &mut b
        ));
        check(
            &b,
            [1.0 / 7.0, 2.0 / 7.0, 0.0, 4.0 / 7.0],
            [0.0, 2.0 / 9.0, 3.0 / 9.0, 4.0 / 9.0],
        );
        // Everything leaving: no load change can be formed.
        let out = [crossing(0, false), crossing(1, false)];
        assert!(!load_change(&[], &out, f, member, &area, &mut b));
        assert!(b.iter().all(|v| *v == 0.0));
    }

    #[test]
    fn a_groups_crossings_are_combinations_of_each_alone() {
        // Areas and a set; a plan of two groups (nodes 1 and 0, then 4 and 5).
        let area = [0.7f32, 1.3, 2.1, 0.4, 1.9, 1.1];
        let member = |i: usize| [true, false, true, true, false, true][i];
        let f = [0.1f32, -0.2, -0.6];
        let nodes = [
            crossing(1, true),
            crossing(0, false),
            crossing(4, true),
            crossing(5, false),
        ];
        let plan = Plan {
            base: (0, 0),
            base_area: (0..6).filter(|&i| member(i)).map(|i| area[i] as f64).sum(),
            nodes,
            areas: nodes.map(|c| area[c.node as usize] as f64),
            len: 4,
            first: 2,
            radius: 0.01,
            force: f,
        };
        // Each node's own change: the first group's from S, the second's from S after it.
        let single: std::vec::Vec<[f32; 18]> = (0..4)
            .map(|i| {
                let mut b = [0.0f32; 18];
                let base = if i < 2 { &nodes[..0] } else { &nodes[..2] };
                assert!(load_change(
                    base,
                    &nodes[i..i + 1],
                    f,
                    member,
                    &area,
                    &mut b
                ));
                b
            })
            .collect();
        // Subsets of the first group from S; the whole first group and subsets of the second.
        for mask in [0b0001u8, 0b0010, 0b0011, 0b0111, 0b1011, 0b1111] {
            let mut want = [0.0f32; 18];
            let (xs, k) = plan.crossings(mask);
            assert!(load_change(&[], &xs[..k], f, member, &area, &mut want));
            let c = plan.combination(mask);
            for e in 0..18 {
                let got: f32 = (0..4).map(|i| c[i] as f32 * single[i][e]).sum();
                assert!((got - want[e]).abs() < 1e-6, "mask {mask:b}, entry {e}");
            }
        }
    }
}
