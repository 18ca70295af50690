//! What the haptic commands play: a model file's bytes or a generated block, and the runtime
//! configuration of the haptic loop.

use palpate_fem::block_model::BlockModel;
use palpate_protocol::model::ModelRecord;
use palpate_runtime::material::LambdaAlpha;
use palpate_runtime::RuntimeConfig;
use std::path::{Path, PathBuf};

use crate::LinkHostError;

/// A model's bytes: read from a file or generated.
pub enum ModelSource {
    /// A model file's bytes.
    File(PathBuf, Vec<u8>),
    /// A generated block.
    Block(Box<BlockModel>),
}

impl ModelSource {
    /// Reads `path`, or generates a block of about `tets` tetrahedra.
    pub fn load(path: Option<&Path>, tets: usize) -> Result<Self, LinkHostError> {
        Ok(match path {
            Some(p) => Self::File(
                p.into(),
                std::fs::read(p).map_err(|e| LinkHostError::Model {
                    file: p.into(),
                    message: format!("reading: {e}"),
                })?,
            ),
            None => Self::Block(Box::new(
                BlockModel::block(tets, LambdaAlpha::from_young_poisson(10e3, 0.3))
                    .map_err(LinkHostError::Block)?,
            )),
        })
    }

    /// The model record.
    pub fn record(&self) -> Result<ModelRecord<'_>, LinkHostError> {
        match self {
            Self::File(p, b) => {
                palpate_protocol::model::decode(b).map_err(|e| LinkHostError::Model {
                    file: p.clone(),
                    message: e.to_string(),
                })
            }
            Self::Block(m) => Ok(m.record()),
        }
    }
}

/// The runtime configuration of the haptic loop: one warm-started PCG solve per sample.
pub fn haptic_config() -> RuntimeConfig {
    RuntimeConfig {
        max_iterations: 100,
        ..Default::default()
    }
}
