//! Checkpoint state as a serde value: the SDK encodes it (postcard) and decodes it, so a
//! module declares *what* its state is, never how it is written.
//!
//! Most modules keep their checkpointed state in one field of a serde type; one line inside
//! `impl Module` writes both [`crate::Module::checkpoint`] and [`crate::Module::restore`]:
//!
//! ```ignore
//! impl Module for Counter {
//!     type Config = ();
//!     fn configure(ctx: &mut Context, _: ()) -> ModuleResult<Self> { /* ... */ }
//!     hng_runtime::checkpoint_field!(state);
//! }
//! ```
//!
//! A module whose state is assembled from several parts (a filter's estimate, a tracker's
//! anchor) names a function that builds the state and one that applies it:
//! `hng_runtime::checkpoint_with!(Self::save_state, Self::load_state)`.
//!
//! A checkpoint that does not decode (another layout, damaged bytes that still passed the
//! file's checksum) makes `restore` fail, and the runtime then tries the previous checkpoint
//! and at last starts clean with a warning (`module::checkpoints`): nothing is half-restored,
//! because the field is assigned only after the whole value decoded.

use serde::Serialize;
use serde::de::DeserializeOwned;

use super::ModuleError;

/// Encodes a module's checkpoint state (postcard); `None` (no checkpoint written, logged by
/// the caller's absence of a file) only if the value cannot be serialized.
pub fn encode_state<T: Serialize>(state: &T) -> Option<Vec<u8>> {
    match postcard::to_allocvec(state) {
        Ok(bytes) => Some(bytes),
        Err(e) => {
            tracing::warn!("checkpoint state not encoded: {e}");
            None
        }
    }
}

/// Decodes a module's checkpoint state written by [`encode_state`]; trailing bytes are an
/// error too (a state of another layout must not pass for this one).
///
/// # Errors
/// The bytes are not a whole value of type `T`.
pub fn decode_state<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, ModuleError> {
    let (value, rest) = postcard::take_from_bytes::<T>(bytes)
        .map_err(|e| format!("checkpoint state does not decode: {e}"))?;
    if !rest.is_empty() {
        return Err(format!(
            "checkpoint state does not decode: {} byte(s) left over",
            rest.len()
        )
        .into());
    }
    Ok(value)
}

/// Writes [`crate::Module::checkpoint`] and [`crate::Module::restore`] for a module whose
/// checkpointed state is the one field `$field` (any `Serialize + DeserializeOwned` type).
/// Use inside `impl Module for ...`. With a second argument, `$load(&mut self, S) ->
/// ModuleResult` applies a restored state (the field and whatever derives from it) instead of
/// the plain assignment.
#[macro_export]
macro_rules! checkpoint_field {
    ($field:ident, $load:path) => {
        fn checkpoint(&self) -> ::std::option::Option<::std::vec::Vec<u8>> {
            $crate::module::encode_state(&self.$field)
        }

        fn restore(&mut self, state: &[u8]) -> $crate::ModuleResult {
            $load(self, $crate::module::decode_state(state)?)
        }
    };
    ($field:ident) => {
        fn checkpoint(&self) -> ::std::option::Option<::std::vec::Vec<u8>> {
            $crate::module::encode_state(&self.$field)
        }

        fn restore(&mut self, state: &[u8]) -> $crate::ModuleResult {
            self.$field = $crate::module::decode_state(state)?;
            ::std::result::Result::Ok(())
        }
    };
}

/// Writes [`crate::Module::checkpoint`] and [`crate::Module::restore`] from two functions:
/// `$save(&self) -> S` builds the state, `$load(&mut self, S) -> ModuleResult` applies it
/// (`S`: any `Serialize + DeserializeOwned` type). Use inside `impl Module for ...`.
#[macro_export]
macro_rules! checkpoint_with {
    ($save:path, $load:path) => {
        fn checkpoint(&self) -> ::std::option::Option<::std::vec::Vec<u8>> {
            $crate::module::encode_state(&$save(self))
        }

        fn restore(&mut self, state: &[u8]) -> $crate::ModuleResult {
            $load(self, $crate::module::decode_state(state)?)
        }
    };
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[derive(Debug, PartialEq, serde::Serialize, serde::Deserialize)]
    struct S {
        a: u64,
        b: f64,
    }

    #[test]
    fn a_state_round_trips_and_damaged_or_foreign_bytes_are_refused() {
        let s = S { a: 7, b: 0.25 };
        let bytes = encode_state(&s).unwrap();
        assert_eq!(decode_state::<S>(&bytes).unwrap(), s);
        // Truncated: refused.
        assert!(decode_state::<S>(&bytes[..bytes.len() - 1]).is_err());
        // Longer than the value (another layout): refused, not half-read.
        let mut longer = bytes.clone();
        longer.push(0);
        let e = decode_state::<S>(&longer).unwrap_err();
        assert!(e.to_string().contains("left over"), "{e}");
    }
}
