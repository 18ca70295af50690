//! What the haptic commands play: a model file's bytes or a generated block, and the runtime
//! configuration of the haptic loop.

use anyhow::Context;
use palpate_fem::block_model::BlockModel;
use palpate_protocol::model::ModelRecord;
use palpate_runtime::material::LambdaAlpha;
use palpate_runtime::RuntimeConfig;
use std::path::{Path, PathBuf};

/// A model's bytes: read from a file or generated.
pub enum ModelSource {
    /// A model file's bytes.
    File(PathBuf, Vec<u8>),
    /// A generated block.
    Block(Box<BlockModel>),
}

impl ModelSource {
    /// Reads `path`, or generates a block of about `tets` tetrahedra.
    pub fn load(path: Option<&Path>, tets: usize) -> anyhow::Result<Self> {
        Ok(match path {
            Some(p) => Self::File(
                p.into(),
                std::fs::read(p).with_context(|| format!("reading model {}", p.display()))?,
            ),
            None => Self::Block(Box::new(
                BlockModel::block(tets, LambdaAlpha::from_young_poisson(10e3, 0.3))
                    .context("generating the block model")?,
            )),
        })
    }

    /// The model record.
    pub fn record(&self) -> anyhow::Result<ModelRecord<'_>> {
        match self {
            Self::File(p, b) => palpate_protocol::model::decode(b)
                .map_err(|e| anyhow::anyhow!("model {}: {e}", p.display())),
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
