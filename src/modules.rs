//! `hng module NAME`: the built-in modules, each run as its own process.
//!
//! A launch file starts a built-in module with `command = ["hng", "module", "NAME"]`; its
//! configuration arrives through `HNG_MODULE_CONFIG` like any module's.

use std::process::ExitCode;

/// The built-in modules' names.
pub const BUILTIN: &[&str] = &[];

/// Runs built-in module `name` as this process.
pub fn run(name: &str) -> ExitCode {
    #[allow(clippy::match_single_binding)]
    match name {
        _ => {
            eprintln!(
                "hng: no built-in module {name:?}; built-in modules: {}",
                if BUILTIN.is_empty() {
                    "none yet".to_string()
                } else {
                    BUILTIN.join(", ")
                }
            );
            ExitCode::from(2)
        }
    }
}
