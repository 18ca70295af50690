//! Caller-provided storage: the runtime never allocates. [`StorageRequirement::for_model`] says how
//! many `f32` and `u32` values a model needs; the caller provides them once (a `Vec` on a host, a
//! `static` array on a microcontroller) and [`Carver`] cuts them into the runtime's arrays.

use crate::config::{Kernel, RuntimeConfig};
use crate::error::RuntimeError;
use palpate_protocol::model::{Blend, ModelRecord};

/// `f32` values per node: x₀, u, u_good, f_cmd, f_app, r, r_full, z, p, q, δ, previous δ, normal
/// (3 each), preconditioner block (6), prescribed normal position, lumped area.
pub const F32_PER_NODE: usize = 13 * 3 + 6 + 2;
/// Element arrays are padded to a whole number of [`crate::kernel::LANES`]-element blocks so
/// every element pass runs the batched (SIMD) kernels without a scalar remainder; the padding
/// elements have zero volume and gradients, so they contribute nothing.
pub const fn padded_elements(t: usize) -> usize {
    t.div_ceil(crate::kernel::LANES) * crate::kernel::LANES
}

/// `f32` values per (padded) element without blending: ∇φ₁..₃ (9), V, λ, α, R (9),
/// quaternion (4), rotated gradients R∇φ₁..₃ (9), element forces of the PCG product (12).
pub const F32_PER_ELEMENT: usize = 9 + 3 + 9 + 4 + 9 + 12;
/// Extra `f32` per element for strain-space blending: the current strain (6).
pub const F32_PER_ELEMENT_STRAIN: usize = 6;
/// Extra `f32` per element for the packed-matrix kernel: C_e and D_e (2 × 78).
pub const F32_PER_ELEMENT_PACKED: usize = 2 * 78;
/// `u32` values per node: constraint flag, coarse aggregate, start of its incidence list (plus
/// one more value in all).
pub const U32_PER_NODE: usize = 3;
/// `u32` values per element: the four node indices and their four incidence entries.
pub const U32_PER_ELEMENT: usize = 8;

/// How much storage a model needs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StorageRequirement {
    /// `f32` values.
    pub f32s: usize,
    /// `u32` values.
    pub u32s: usize,
}

impl StorageRequirement {
    /// Storage needed to run `record` with `config`.
    pub fn for_model(record: &ModelRecord<'_>, config: &RuntimeConfig) -> Self {
        let n = record.node_count as usize;
        let t = record.element_count as usize;
        let tp = padded_elements(t);
        let mut per_element = 0;
        if matches!(record.blend, Blend::Strain { .. }) {
            per_element += F32_PER_ELEMENT_STRAIN;
        }
        if config.kernel == Kernel::Packed {
            per_element += F32_PER_ELEMENT_PACKED;
        }
        let coarse = crate::coarse::coarse_f32s(crate::coarse::aggregate_capacity(
            config.coarse_aggregates,
            n,
        ));
        Self {
            f32s: n * F32_PER_NODE + tp * F32_PER_ELEMENT + t * per_element + coarse,
            u32s: n * U32_PER_NODE + 1 + tp * U32_PER_ELEMENT,
        }
    }

    /// Total bytes of the two pools.
    pub fn bytes(&self) -> usize {
        4 * (self.f32s + self.u32s)
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
}
