//! A caller's checks of each module while a launch file is validated ([`ModuleCheck`]), and
//! placing their problems in the file: `hng run` checks that `["hng", "module", NAME]` names a
//! built-in module and that its `[module.config]` parses as that module's configuration.

use toml::de::{DeTable, DeValue};

use super::{Cx, LaunchErrorKind, ModuleSpec, RawModule, key_at};

/// What a [`ModuleCheck`] found wrong with a module.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ModuleProblem {
    /// `command[index]` is wrong (e.g. an unknown built-in module name).
    Command {
        /// Index in `command` (0 is the program).
        index: usize,
        /// What is wrong.
        message: String,
    },
    /// The `[module.config]` table does not fit the module's configuration type.
    Config {
        /// Where, in the module's config as passed on ([`ModuleSpec::config`]); mapped back
        /// to the launch file's key.
        span: Option<std::ops::Range<usize>>,
        /// What is wrong.
        message: String,
    },
}

/// A caller's check of each module (its command and its typed configuration), run while
/// the file is validated so its problems are reported with the others, before anything
/// starts. `hng run` checks its built-in modules' names and configuration types.
pub type ModuleCheck =
    std::sync::Arc<dyn Fn(&ModuleSpec) -> Result<(), ModuleProblem> + Send + Sync>;

impl Cx<'_> {
    /// Reports a [`ModuleCheck`]'s problem at its place in the launch file.
    pub(super) fn module_problem(
        &mut self,
        problem: ModuleProblem,
        raw: &RawModule,
        table: Option<&DeTable<'_>>,
        config_text: &str,
        prefix: &str,
    ) {
        match problem {
            ModuleProblem::Command { index, message } => {
                let span = raw
                    .command
                    .get_ref()
                    .get(index)
                    .map_or_else(|| raw.command.span(), |a| a.span());
                self.err(
                    span,
                    Some(format!("{prefix}.command[{index}]")),
                    LaunchErrorKind::InvalidValue(message),
                );
            }
            ModuleProblem::Config { span, message } => {
                // The key the module's parser stopped at, in the passed-on text ...
                let key = span.and_then(|sp| {
                    let (parsed, errors) = DeTable::parse_recoverable(config_text);
                    if errors.is_empty() {
                        key_at(parsed.get_ref(), sp.start)
                    } else {
                        None
                    }
                });
                // ... and the same key in the launch file.
                let config = table.and_then(|t| table_entry(t, "config"));
                let found = key.as_deref().and_then(|k| {
                    let path: Vec<&str> = k.split('.').collect();
                    config.as_ref().and_then(|(_, v)| key_span(v, &path))
                });
                let whole = raw
                    .config
                    .as_ref()
                    .map(|c| c.span())
                    .or_else(|| config.as_ref().map(|(k, _)| k.clone()))
                    .unwrap_or_else(|| raw.name.span());
                let field = match &key {
                    Some(k) if found.is_some() => format!("{prefix}.config.{k}"),
                    _ => format!("{prefix}.config"),
                };
                self.err(
                    found.unwrap_or(whole),
                    Some(field),
                    LaunchErrorKind::InvalidValue(message),
                );
            }
        }
    }
}

/// The span of key `name` in `table`, and its value.
fn table_entry<'a, 'b>(
    table: &'a DeTable<'b>,
    name: &str,
) -> Option<(std::ops::Range<usize>, &'a DeValue<'b>)> {
    table
        .iter()
        .find(|(k, _)| k.get_ref() == name)
        .map(|(k, v)| (k.span(), v.get_ref()))
}

/// The span of the key at dotted `path` under `value` (a table).
fn key_span(value: &DeValue<'_>, path: &[&str]) -> Option<std::ops::Range<usize>> {
    let (first, rest) = path.split_first()?;
    let DeValue::Table(t) = value else {
        return None;
    };
    let (span, v) = table_entry(t, first)?;
    if rest.is_empty() {
        Some(span)
    } else {
        key_span(v, rest)
    }
}
