//! A module's checkpoints: the latest one and, beside it, the last good one before it.
//!
//! Every save first moves the current checkpoint aside (`<name>.prev.ckpt`, an atomic
//! rename) and then writes the new one, so a checkpoint that turns out unusable (corrupted on
//! disk, or rejected by the module) is replaced by the one before it rather than by a clean
//! start. A module for which a clean start in the middle of a run would be wrong (the
//! simulator: the world would start again and its clock go back) sets
//! [`Module::CLEAN_START_AFTER_BAD_CHECKPOINT`] to false and then refuses to start when
//! neither checkpoint is usable.
//!
//! A checkpoint identical to the one this process last wrote is not written again (a module
//! whose state did not change, such as Maps or the laser driver, would otherwise pay a
//! rename, two `fsync`s and a directory scan every period for nothing).

use std::path::Path;

use super::{Context, Module, ModuleError};
use crate::checkpoint::CheckpointStore;

/// The latest checkpoint and the one before it.
#[derive(Debug)]
pub(super) struct Checkpoints {
    latest: CheckpointStore,
    previous: Option<CheckpointStore>,
    /// What this process last wrote (state version and bytes).
    written: std::cell::RefCell<Option<(u32, Vec<u8>)>>,
}

impl Checkpoints {
    /// The checkpoints of module `name` in `dir`; `None` (after a warning) when they cannot
    /// be used.
    pub(super) fn open(dir: &Path, name: &str) -> Option<Checkpoints> {
        match CheckpointStore::new(dir, name) {
            Ok(latest) => Some(Checkpoints {
                latest,
                previous: CheckpointStore::new(dir, &format!("{name}.prev")).ok(),
                written: std::cell::RefCell::new(None),
            }),
            Err(e) => {
                tracing::warn!(module = %name, "checkpoints disabled: {e}");
                None
            }
        }
    }

    /// Restores `module` from the latest usable checkpoint. `Ok` also when there is none
    /// (a first start) or, for modules that allow it, when none is usable (a clean start);
    /// `Err` when none is usable and the module refuses a clean start.
    pub(super) fn restore<M: Module>(&self, module: &mut M, name: &str) -> Result<(), ModuleError> {
        let mut problems = Vec::new();
        for (which, store) in [
            ("latest", Some(&self.latest)),
            ("previous", self.previous.as_ref()),
        ] {
            let Some(store) = store else { continue };
            match store.load(M::STATE_VERSION) {
                Ok(Some(bytes)) => match module.restore(&bytes) {
                    Ok(()) => {
                        if problems.is_empty() {
                            tracing::info!(module = %name, bytes = bytes.len(), "state restored from checkpoint");
                        } else {
                            tracing::warn!(module = %name, bytes = bytes.len(), problems = ?problems, "latest checkpoint unusable: state restored from the one before it");
                        }
                        return Ok(());
                    }
                    Err(e) => problems.push(format!("{which}: rejected by the module: {e}")),
                },
                Ok(None) => {}
                Err(e) => problems.push(format!("{which}: {e}")),
            }
        }
        if problems.is_empty() {
            return Ok(()); // first start
        }
        if M::CLEAN_START_AFTER_BAD_CHECKPOINT {
            tracing::warn!(module = %name, problems = ?problems, "no usable checkpoint, starting clean");
            return Ok(());
        }
        Err(format!(
            "no usable checkpoint ({}), and this module does not start clean in the middle of a run",
            problems.join("; ")
        )
        .into())
    }

    /// Saves `bytes`, keeping the checkpoint it replaces as the previous one.
    pub(super) fn save(
        &self,
        state_version: u32,
        bytes: &[u8],
    ) -> Result<(), crate::checkpoint::CheckpointError> {
        if self
            .written
            .borrow()
            .as_ref()
            .is_some_and(|(v, b)| *v == state_version && b.as_slice() == bytes)
        {
            return Ok(()); // on disk already
        }
        if let Some(prev) = &self.previous
            && self.latest.path().exists()
            && let Err(e) = std::fs::rename(self.latest.path(), prev.path())
        {
            tracing::debug!("keeping the previous checkpoint: {e}");
        }
        let saved = self.latest.save(state_version, bytes);
        *self.written.borrow_mut() = saved.is_ok().then(|| (state_version, bytes.to_vec()));
        saved
    }
}

/// Writes the module's checkpoint, if it gives one (a failure is logged, the module runs on).
pub(super) fn save_checkpoint<M: Module>(
    module: &M,
    store: &Checkpoints,
    ctx: &mut Context,
    name: &str,
) {
    if let Some(bytes) = module.checkpoint() {
        match store.save(M::STATE_VERSION, &bytes) {
            Ok(()) => ctx.checkpoints += 1,
            Err(e) => tracing::warn!(module = %name, "checkpoint not written: {e}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_unchanged_checkpoint_is_not_written_again() {
        let dir = std::env::temp_dir().join(format!("hng-ckpts-same-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let store = Checkpoints::open(&dir, "m").expect("checkpoints");
        let prev = dir.join("m.prev.ckpt");
        store.save(1, b"state a").expect("save");
        assert!(store.latest.path().exists());
        assert!(!prev.exists());
        // The same state again: nothing moves (a write would first move the latest aside).
        store.save(1, b"state a").expect("save");
        assert!(!prev.exists(), "an identical checkpoint was written again");
        // Another version of the same bytes, then other bytes: written.
        store.save(2, b"state a").expect("save");
        assert!(prev.exists());
        std::fs::remove_file(&prev).expect("remove");
        store.save(2, b"state b").expect("save");
        assert!(prev.exists());
        assert_eq!(
            store.latest.load(2).expect("load").as_deref(),
            Some(&b"state b"[..])
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
