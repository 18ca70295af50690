//! Caller-provided storage: the runtime never allocates. [`StorageRequirement::for_model`] says how
//! many `f32` and `u32` values a model needs; the caller provides them once (a `Vec` on a host, a
//! `static` array on a microcontroller) and [`Carver`] cuts them into the runtime's arrays.
//!
//! Why one description: the size asked of the caller and the slices cut from it must agree, and
//! when they were written twice (constants here, carving in the constructor) every new array had
//! to be added in two places. Now each room of the runtime (nodes, contact set, elements, element
//! forces, preconditioner, PCG work) lists its arrays once, as a `RoomLayout` of lengths per
//! pool in carving order; `Layout` gathers the rooms. [`StorageRequirement::for_model`] sums
//! that list and `Runtime::new` carves it, room by room, array by array (faer's `StackReq`
//! pattern), so the two can never disagree.

use crate::config::{Kernel, RuntimeConfig};
use crate::error::RuntimeError;
use palpate_protocol::model::{Blend, ModelRecord};

/// `f32` values per node: x₀, u, u_good, f_cmd, f_app, r_full, δ, previous δ, r_start (the node
/// state, 3 each), lumped area (1); normal (3) and prescribed normal position (1) (the contact set);
/// r, z, p, q (the PCG work, 3 each); preconditioner block (6) — without a lumped probe's
/// anticipation ([`crate::anticipate`], 33 more when configured). Derived from `Layout`.
pub const F32_PER_NODE: usize = Layout::per_node().0;
/// Element arrays are padded to a whole number of [`crate::kernel::LANES`]-element blocks so
/// every element pass runs the batched (SIMD) kernels without a scalar remainder; the padding
/// elements have zero volume and gradients, so they contribute nothing.
pub const fn padded_elements(t: usize) -> usize {
    t.div_ceil(crate::kernel::LANES) * crate::kernel::LANES
}

/// `f32` values per (padded) element without blending: ∇φ₁..₃ (9), V, λ, α, R (9),
/// quaternion (4), rotated gradients R∇φ₁..₃ (9), element forces of the PCG product (12).
/// Derived from `Layout`.
pub const F32_PER_ELEMENT: usize = Layout::per_padded_element().0;
/// Extra `f32` per element for strain-space blending: the current strain (6), plus one per
/// fitted set for the neighbour-distance scratch (`Dims::blend_sets`). Derived from `Layout`.
pub const F32_PER_ELEMENT_STRAIN: usize = Layout::per_element(true, false);
/// Extra `f32` per element for the packed-matrix kernel: C_e and D_e (2 × 78). Derived from
/// `Layout`.
pub const F32_PER_ELEMENT_PACKED: usize = Layout::per_element(false, true);
/// `u32` values per node: constraint flag, coarse aggregate, start of its incidence list (plus
/// one more value in all). Derived from `Layout`.
pub const U32_PER_NODE: usize = Layout::per_node().1;
/// `u32` values per element: the four node indices and their four incidence entries. Derived
/// from `Layout`.
pub const U32_PER_ELEMENT: usize = Layout::per_padded_element().1;

/// How much storage a model needs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StorageRequirement {
    /// `f32` values.
    pub f32s: usize,
    /// `u32` values.
    pub u32s: usize,
}

impl StorageRequirement {
    /// Storage needed to run `record` with `config`: the sum of the runtime's `Layout`.
    pub fn for_model(record: &ModelRecord<'_>, config: &RuntimeConfig) -> Self {
        let layout = Layout::of(&Dims::of(record, config));
        Self {
            f32s: layout.f32s(),
            u32s: layout.u32s(),
        }
    }

    /// Total bytes of the two pools.
    pub fn bytes(&self) -> usize {
        4 * (self.f32s + self.u32s)
    }
}

/// The sizes a layout depends on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Dims {
    /// Nodes n.
    pub nodes: usize,
    /// Elements t.
    pub elements: usize,
    /// Elements padded to whole LANES blocks ([`padded_elements`]).
    pub padded: usize,
    /// The model blends in strain space (each element keeps its strain).
    pub strain: bool,
    /// Fitted sets of a strain-space blend (0 otherwise): each element keeps its strain's
    /// distance to every set's centre, computed once per blend and read by every element that
    /// lists it as a neighbour.
    pub blend_sets: usize,
    /// The packed-matrix kernel runs (each element keeps C_e, D_e).
    pub packed: bool,
    /// Aggregates of the coarse space ([`crate::coarse::aggregate_capacity`]).
    pub aggregates: usize,
    /// A lumped probe's rim crossings are anticipated ([`crate::anticipate`]): its solve's
    /// vectors are carved.
    pub anticipate: bool,
}

impl Dims {
    /// The sizes of `record` run with `config`.
    pub(crate) fn of(record: &ModelRecord<'_>, config: &RuntimeConfig) -> Self {
        let n = record.node_count as usize;
        let t = record.element_count as usize;
        Self {
            nodes: n,
            elements: t,
            padded: padded_elements(t),
            strain: matches!(record.blend, Blend::Strain { .. }),
            blend_sets: match record.blend {
                Blend::Strain { .. } => record.parameters.count as usize,
                _ => 0,
            },
            packed: config.kernel == Kernel::Packed,
            aggregates: crate::coarse::aggregate_capacity(config.coarse_aggregates, n),
            anticipate: config.anticipation_iterations > 0
                && config.contact_rule == crate::contact_rule::ContactRule::Lumped,
        }
    }
}

/// The arrays of one room: the length of each, from the `f32` pool (`F` arrays) and from the
/// `u32` pool (`U` arrays), in carving order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct RoomLayout<const F: usize, const U: usize> {
    /// Lengths of the `f32` arrays.
    pub f32s: [usize; F],
    /// Lengths of the `u32` arrays.
    pub u32s: [usize; U],
}

impl<const F: usize, const U: usize> RoomLayout<F, U> {
    /// Total `f32` values of the room.
    pub const fn f32_total(&self) -> usize {
        sum(&self.f32s)
    }

    /// Total `u32` values of the room.
    pub const fn u32_total(&self) -> usize {
        sum(&self.u32s)
    }

    /// Cuts the room's arrays, in layout order, off the two pools.
    #[allow(clippy::type_complexity)]
    pub fn carve<'a>(
        &self,
        f: &mut Carver<'a, f32>,
        u: &mut Carver<'a, u32>,
    ) -> Result<([&'a mut [f32]; F], [&'a mut [u32]; U]), RuntimeError> {
        Ok((f.take_array(self.f32s)?, u.take_array(self.u32s)?))
    }
}

const fn sum<const K: usize>(lens: &[usize; K]) -> usize {
    let mut s = 0;
    let mut k = 0;
    while k < K {
        s += lens[k];
        k += 1;
    }
    s
}

/// The runtime's whole storage: every room's arrays. `Runtime::new` carves the rooms in the
/// order of the fields; [`Layout::f32s`] and [`Layout::u32s`] sum them (`Layout::totals`). Both
/// destructure the struct exhaustively, so a room added here must be both sized and carved.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Layout {
    /// [`crate::nodes::NodeState`].
    pub nodes: RoomLayout<11, 0>,
    /// [`crate::contact_set::ContactSet`].
    pub contact: RoomLayout<3, 1>,
    /// [`crate::pcg::PcgWork`].
    pub work: RoomLayout<4, 0>,
    /// [`crate::two_level::TwoLevel`].
    pub precond: RoomLayout<2, 1>,
    /// [`crate::element_state::ElementState`].
    pub elements: RoomLayout<10, 1>,
    /// [`crate::stiffness::ElementForces`].
    pub forces: RoomLayout<1, 2>,
    /// [`crate::anticipate::Anticipation`].
    pub anticipation: RoomLayout<12, 0>,
}

impl Layout {
    /// The layout for `d`.
    pub(crate) const fn of(d: &Dims) -> Self {
        Self {
            nodes: crate::nodes::NodeState::layout(d),
            contact: crate::contact_set::ContactSet::layout(d),
            work: crate::pcg::PcgWork::layout(d),
            elements: crate::element_state::ElementState::layout(d),
            forces: crate::stiffness::ElementForces::layout(d),
            precond: crate::two_level::TwoLevel::layout(d),
            anticipation: crate::anticipate::Anticipation::layout(d),
        }
    }

    /// Total `f32` values.
    pub(crate) const fn f32s(&self) -> usize {
        self.totals().0
    }

    /// Total `u32` values.
    pub(crate) const fn u32s(&self) -> usize {
        self.totals().1
    }

    /// Every room's (`f32`, `u32`) values, summed; the one exhaustive destructuring that sizes.
    const fn totals(&self) -> (usize, usize) {
        let Layout {
            nodes,
            contact,
            work,
            elements,
            forces,
            precond,
            anticipation,
        } = self;
        (
            nodes.f32_total()
                + contact.f32_total()
                + work.f32_total()
                + elements.f32_total()
                + forces.f32_total()
                + precond.f32_total()
                + anticipation.f32_total(),
            nodes.u32_total()
                + contact.u32_total()
                + work.u32_total()
                + elements.u32_total()
                + forces.u32_total()
                + precond.u32_total()
                + anticipation.u32_total(),
        )
    }

    const fn dims(nodes: usize, elements: usize, padded: usize, s: bool, p: bool) -> Dims {
        Dims {
            nodes,
            elements,
            padded,
            strain: s,
            blend_sets: 0,
            packed: p,
            aggregates: 0,
            anticipate: false,
        }
    }

    /// (`f32`, `u32`) values one more node adds.
    const fn per_node() -> (usize, usize) {
        let (a, b) = (
            Self::of(&Self::dims(1, 0, 0, false, false)),
            Self::of(&Self::dims(0, 0, 0, false, false)),
        );
        (a.f32s() - b.f32s(), a.u32s() - b.u32s())
    }

    /// (`f32`, `u32`) values one more padded element adds.
    const fn per_padded_element() -> (usize, usize) {
        let (a, b) = (
            Self::of(&Self::dims(0, 0, 1, false, false)),
            Self::of(&Self::dims(0, 0, 0, false, false)),
        );
        (a.f32s() - b.f32s(), a.u32s() - b.u32s())
    }

    /// `f32` values one more (unpadded) element adds with strain blending / the packed kernel.
    const fn per_element(strain: bool, packed: bool) -> usize {
        Self::of(&Self::dims(0, 1, 0, strain, packed)).f32s()
            - Self::of(&Self::dims(0, 1, 0, false, false)).f32s()
    }
}

/// Cuts consecutive sub-slices off a caller-provided slice.
pub struct Carver<'a, T> {
    rest: &'a mut [T],
    what: &'static str,
    needed: usize,
    available: usize,
}

impl<'a, T: Copy + Default> Carver<'a, T> {
    /// Starts carving `storage`; `needed` is the total that will be taken (checked up front).
    pub fn new(
        storage: &'a mut [T],
        needed: usize,
        what: &'static str,
    ) -> Result<Self, RuntimeError> {
        let available = storage.len();
        if available < needed {
            return Err(RuntimeError::CapacityExceeded {
                what,
                needed,
                available,
            });
        }
        Ok(Self {
            rest: storage,
            what,
            needed,
            available,
        })
    }

    /// Takes the next `n` values, zeroed.
    pub fn take(&mut self, n: usize) -> Result<&'a mut [T], RuntimeError> {
        if self.rest.len() < n {
            return Err(RuntimeError::CapacityExceeded {
                what: self.what,
                needed: self.needed.max(self.available - self.rest.len() + n),
                available: self.available,
            });
        }
        let (head, tail) = core::mem::take(&mut self.rest).split_at_mut(n);
        self.rest = tail;
        head.iter_mut().for_each(|v| *v = T::default());
        Ok(head)
    }

    /// Takes the next `K` arrays of the given lengths, zeroed, in order.
    pub fn take_array<const K: usize>(
        &mut self,
        lens: [usize; K],
    ) -> Result<[&'a mut [T]; K], RuntimeError> {
        let mut out: [&'a mut [T]; K] = core::array::from_fn(|_| <&mut [T]>::default());
        for (o, n) in out.iter_mut().zip(lens) {
            *o = self.take(n)?;
        }
        Ok(out)
    }
}

// What is tested: that a runtime runs in exactly the storage this file asks for, under every
// configuration that sizes a room differently, and is refused one value short
// (`tests/tests/cross_crate/runtime_storage.rs`).
