//! Keys a launch file no longer has: durations became seconds as numbers (`heartbeat_period =
//! "200ms"` is now `heartbeat_period_s = 0.2`). Each old key is reported with its new name
//! (and, when its value reads as a duration, the value to write), then taken out of the table
//! so the rest of it is still checked.

use toml::de::{DeTable, DeValue};

use super::{Cx, LaunchErrorKind};
use crate::units::parse_duration;

/// The supervision settings that were durations with a unit, by their old names.
const RENAMED: [&str; 9] = [
    "backoff_initial",
    "backoff_max",
    "backoff_reset_after",
    "give_up_window",
    "heartbeat_period",
    "heartbeat_timeout",
    "start_timeout",
    "checkpoint_period",
    "stop_timeout",
];

impl Cx<'_> {
    /// Reports and removes every old key of `table` (`[defaults]` or a module, at `prefix`).
    pub(crate) fn renamed_keys(&mut self, table: &mut DeTable<'_>, prefix: &str) {
        let mut found = Vec::new();
        for (key, value) in table.iter() {
            let old: &str = key.get_ref();
            if !RENAMED.contains(&old) {
                continue;
            }
            let new = format!("{old}_s");
            let mut message = format!("`{old}` is now `{new}` (seconds)");
            if let DeValue::String(text) = value.get_ref() {
                match text.trim() {
                    "off" => message.push_str(&format!(": write {new} = \"off\"")),
                    t => {
                        if let Ok(d) = parse_duration(t) {
                            message.push_str(&format!(": write {new} = {}", d.as_secs_f64()));
                        }
                    }
                }
            }
            found.push((key.clone(), format!("{prefix}.{old}"), message));
        }
        for (key, field, message) in found {
            table.remove(&key);
            self.err(
                key.span(),
                Some(field),
                LaunchErrorKind::UnknownField(message),
            );
        }
    }
}
