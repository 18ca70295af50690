//! The host side's memory for a [`Runtime`]: the runtime allocates nothing and runs in storage
//! its caller sizes once from the model and the configuration; on the host that is two vectors.

use palpate_protocol::model::ModelRecord;
use palpate_runtime::{Runtime, RuntimeConfig, RuntimeError, StorageRequirement};

/// The caller's memory of a runtime, sized once from a model and a configuration.
pub struct Storage {
    f32s: Vec<f32>,
    u32s: Vec<u32>,
}

impl Storage {
    /// Zeroed storage of the size the runtime asks for `record` under `config`.
    pub fn for_model(record: &ModelRecord<'_>, config: &RuntimeConfig) -> Self {
        let need = StorageRequirement::for_model(record, config);
        Self {
            f32s: vec![0f32; need.f32s],
            u32s: vec![0u32; need.u32s],
        }
    }

    /// A runtime of `record` in this storage.
    pub fn runtime<'a>(
        &'a mut self,
        record: ModelRecord<'a>,
        config: RuntimeConfig,
    ) -> Result<Runtime<'a>, RuntimeError> {
        Runtime::new(record, &mut self.f32s, &mut self.u32s, config)
    }
}
