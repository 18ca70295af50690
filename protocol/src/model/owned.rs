//! Owned storage for a [`ModelRecord`] (feature `alloc`): the fitter's export and the protocol's
//! own tests both keep a model's arrays in vectors and borrow a record from them, so the one
//! field-by-field mapping lives here rather than in each of them. The firmware does not turn the
//! feature on: the runtime only ever borrows records from a decoded container.

use alloc::string::String;
use alloc::vec::Vec;

use super::{Blend, F32s, ModelRecord, ParameterLayout, ParameterSets, Provenance, U32s, Units};

/// Blend data in owned little-endian byte vectors (the owned side of [`Blend`]).
#[derive(Debug, Clone, PartialEq)]
pub enum OwnedBlend {
    /// [`Blend::None`].
    None,
    /// [`Blend::Deformation`].
    Deformation {
        /// `count × 3n` centres, f32.
        centres: Vec<u8>,
        /// w^λ, f32.
        weights_lambda: Vec<u8>,
        /// w^α, f32.
        weights_alpha: Vec<u8>,
    },
    /// [`Blend::Strain`].
    Strain {
        /// Decay c (1/m²).
        decay: f32,
        /// Neighbours per element k.
        neighbours: u32,
        /// `t × k` neighbour indices, u32.
        neighbour_index: Vec<u8>,
        /// `t × k` weights, f32.
        neighbour_weight: Vec<u8>,
        /// `count × t × 6` strain centres, f32.
        centres: Vec<u8>,
        /// `t × count` w^λ, f32.
        weights_lambda: Vec<u8>,
        /// `t × count` w^α, f32.
        weights_alpha: Vec<u8>,
    },
}

/// A model record's storage: every array as little-endian bytes, every string owned. Units are
/// always SI. [`OwnedModel::record`] borrows the [`ModelRecord`]; nothing is validated here
/// (a test may keep a malformed model on purpose — `encode` and `decode` validate).
#[derive(Debug, Clone, PartialEq)]
pub struct OwnedModel {
    /// [`Provenance::tool`].
    pub tool: String,
    /// [`Provenance::created`].
    pub created: String,
    /// [`Provenance::source`].
    pub source: String,
    /// [`Provenance::notes`].
    pub notes: String,
    /// [`ModelRecord::node_count`].
    pub node_count: u32,
    /// [`ModelRecord::element_count`].
    pub element_count: u32,
    /// [`ModelRecord::rest_positions`], f32.
    pub rest_positions: Vec<u8>,
    /// [`ModelRecord::node_tags`], u32.
    pub node_tags: Vec<u8>,
    /// [`ModelRecord::tets`], u32.
    pub tets: Vec<u8>,
    /// [`ModelRecord::fixed_nodes`], u32.
    pub fixed_nodes: Vec<u8>,
    /// [`ModelRecord::surface_triangles`], u32.
    pub surface_triangles: Vec<u8>,
    /// [`ModelRecord::c_packed`], f32.
    pub c_packed: Vec<u8>,
    /// [`ModelRecord::d_packed`], f32.
    pub d_packed: Vec<u8>,
    /// [`ParameterSets::layout`].
    pub layout: ParameterLayout,
    /// [`ParameterSets::count`].
    pub count: u32,
    /// [`ParameterSets::lambda`], f32.
    pub lambda: Vec<u8>,
    /// [`ParameterSets::alpha`], f32.
    pub alpha: Vec<u8>,
    /// [`ModelRecord::blend`].
    pub blend: OwnedBlend,
}

impl OwnedModel {
    /// The record borrowing these buffers.
    pub fn record(&self) -> ModelRecord<'_> {
        let blend = match &self.blend {
            OwnedBlend::None => Blend::None,
            OwnedBlend::Deformation {
                centres,
                weights_lambda,
                weights_alpha,
            } => Blend::Deformation {
                centres: F32s(centres),
                weights_lambda: F32s(weights_lambda),
                weights_alpha: F32s(weights_alpha),
            },
            OwnedBlend::Strain {
                decay,
                neighbours,
                neighbour_index,
                neighbour_weight,
                centres,
                weights_lambda,
                weights_alpha,
            } => Blend::Strain {
                decay: *decay,
                neighbours: *neighbours,
                neighbour_index: U32s(neighbour_index),
                neighbour_weight: F32s(neighbour_weight),
                centres: F32s(centres),
                weights_lambda: F32s(weights_lambda),
                weights_alpha: F32s(weights_alpha),
            },
        };
        ModelRecord {
            units: Units::Si,
            provenance: Provenance {
                tool: &self.tool,
                created: &self.created,
                source: &self.source,
                notes: &self.notes,
            },
            node_count: self.node_count,
            element_count: self.element_count,
            rest_positions: F32s(&self.rest_positions),
            node_tags: U32s(&self.node_tags),
            tets: U32s(&self.tets),
            fixed_nodes: U32s(&self.fixed_nodes),
            surface_triangles: U32s(&self.surface_triangles),
            c_packed: F32s(&self.c_packed),
            d_packed: F32s(&self.d_packed),
            parameters: ParameterSets {
                layout: self.layout,
                count: self.count,
                lambda: F32s(&self.lambda),
                alpha: F32s(&self.alpha),
            },
            blend,
        }
    }
}
