//! Loading: from launch-file text to a validated [`LaunchPlan`], every problem reported.

use std::collections::HashMap;
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};

use toml::de::{DeTable, DeValue, ValueDeserializer};

use super::raw::{RawModule, RawSettings, RawTop, S};
use super::settings::Merged;
use super::*;

/// Read and validate a launch file.
pub fn load(file: &Path, opts: &LoadOptions) -> Result<LaunchPlan, LaunchErrors> {
    match std::fs::read_to_string(file) {
        Ok(src) => parse(&src, file, opts),
        Err(e) => Err(LaunchErrors(vec![LaunchError {
            file: file.to_owned(),
            line: 1,
            column: 1,
            field: None,
            kind: LaunchErrorKind::Read(e.to_string()),
        }])),
    }
}

/// Validate launch-file text; `file` is used in messages and to resolve
/// relative program paths.
pub fn parse(src: &str, file: &Path, opts: &LoadOptions) -> Result<LaunchPlan, LaunchErrors> {
    let mut cx = Cx {
        src,
        file,
        errors: Vec::new(),
    };
    let plan = cx.parse(opts);
    let mut errors = cx.errors;
    if errors.is_empty()
        && let Some(plan) = plan
    {
        return Ok(plan);
    }
    errors.sort_by_key(|e| (e.line, e.column));
    errors.dedup();
    Err(LaunchErrors(errors))
}

pub(crate) struct Cx<'a> {
    pub(crate) src: &'a str,
    pub(crate) file: &'a Path,
    pub(crate) errors: Vec<LaunchError>,
}

/// 1-based line and column (in characters) of a byte offset.
pub fn line_col(src: &str, offset: usize) -> (usize, usize) {
    let offset = offset.min(src.len());
    let before = src.get(..offset).unwrap_or(src);
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let column = before.get(line_start..).map_or(0, |s| s.chars().count()) + 1;
    (line, column)
}

impl Cx<'_> {
    pub(crate) fn err(
        &mut self,
        span: std::ops::Range<usize>,
        field: Option<String>,
        kind: LaunchErrorKind,
    ) {
        let (line, column) = line_col(self.src, span.start);
        self.errors.push(LaunchError {
            file: self.file.to_owned(),
            line,
            column,
            field,
            kind,
        });
    }

    pub(crate) fn line_of(&self, offset: usize) -> usize {
        line_col(self.src, offset).0
    }

    /// Turn a serde error of `value` (deserialized at `prefix`) into a LaunchError.
    pub(crate) fn serde_err(
        &mut self,
        e: &toml::de::Error,
        table: Option<&DeTable<'_>>,
        prefix: &str,
    ) {
        let span = e.span().unwrap_or(0..0);
        let msg = e.message().to_owned();
        let key = table.and_then(|t| key_at(t, span.start));
        let field = match key {
            Some(k) if prefix.is_empty() => k,
            Some(k) => format!("{prefix}.{k}"),
            None => prefix.to_owned(),
        };
        let kind = if msg.starts_with("unknown field") {
            LaunchErrorKind::UnknownField(msg)
        } else if msg.starts_with("missing field") {
            LaunchErrorKind::MissingField(msg)
        } else if msg.starts_with("invalid type") {
            LaunchErrorKind::WrongType(msg)
        } else if msg.starts_with("data did not match any variant") {
            LaunchErrorKind::WrongType("expected a number or a string".to_owned())
        } else {
            LaunchErrorKind::InvalidValue(msg)
        };
        let field = if field.is_empty() { None } else { Some(field) };
        self.err(span, field, kind);
    }

    pub(crate) fn parse(&mut self, opts: &LoadOptions) -> Option<LaunchPlan> {
        let (root, syntax) = DeTable::parse_recoverable(self.src);
        if !syntax.is_empty() {
            for e in syntax {
                let span = e.span().unwrap_or(0..0);
                self.err(span, None, LaunchErrorKind::Syntax(e.message().to_owned()));
            }
            return None;
        }
        let root_span = root.span();
        let mut root = root.into_inner();

        // Split off the modules so every one is deserialized (and reported) on its own.
        let mut modules_value = root
            .keys()
            .find(|k| k.get_ref() == "module")
            .cloned()
            .and_then(|key| root.remove(&key));
        // Old spellings, all reported at once (the rest of each table is still checked).
        for (key, value) in root.iter_mut() {
            if key.get_ref() == "defaults"
                && let DeValue::Table(t) = value.get_mut()
            {
                self.renamed_keys(t, "defaults");
            }
        }
        if let Some(DeValue::Array(arr)) = modules_value.as_mut().map(|v| v.get_mut()) {
            for (i, el) in arr.iter_mut().enumerate() {
                if let DeValue::Table(t) = el.get_mut() {
                    self.renamed_keys(t, &format!("module[{i}]"));
                }
            }
        }
        let top_table = root.clone();
        let top = match RawTop::deserialize(ValueDeserializer::from(Spanned::new(
            root_span,
            DeValue::Table(root),
        ))) {
            Ok(t) => Some(t),
            Err(e) => {
                self.serde_err(&e, Some(&top_table), "");
                None
            }
        };

        let mut raws: Vec<(
            usize,
            RawModule,
            std::ops::Range<usize>,
            Option<DeTable<'_>>,
        )> = Vec::new();
        match modules_value {
            None => {
                if let Some(top) = &top {
                    self.err(
                        top.system.span(),
                        Some("module".to_owned()),
                        LaunchErrorKind::MissingField(
                            "no [[module]] tables: a system needs at least one module".to_owned(),
                        ),
                    );
                }
            }
            Some(v) => match v.get_ref() {
                DeValue::Array(arr) => {
                    for (i, el) in arr.iter().enumerate() {
                        let table = match el.get_ref() {
                            DeValue::Table(t) => Some(t.clone()),
                            _ => None,
                        };
                        let prefix = format!("module[{i}]");
                        match RawModule::deserialize(ValueDeserializer::from(el.clone())) {
                            Ok(m) => raws.push((i, m, el.span(), table)),
                            Err(e) => self.serde_err(&e, table.as_ref(), &prefix),
                        }
                    }
                }
                _ => self.err(
                    v.span(),
                    Some("module".to_owned()),
                    LaunchErrorKind::WrongType(
                        "`module` must be an array of tables: write [[module]]".to_owned(),
                    ),
                ),
            },
        }

        let top = top?;
        let empty = RawSettings::default();
        let defaults = top.defaults.as_ref().map_or(&empty, |d| d.get_ref());
        // Validate [defaults] on its own too, so errors there are reported once.
        let self_exe = opts
            .self_exe
            .clone()
            .or_else(|| std::env::current_exe().ok());
        let system = top.system.get_ref().trim().to_owned();
        if system.is_empty() {
            self.err(
                top.system.span(),
                Some("system".to_owned()),
                LaunchErrorKind::InvalidValue("the system name must not be empty".to_owned()),
            );
        }
        self.validate_settings_alone(defaults);
        let sim_clock = match &top.clock {
            None => false,
            Some(c) => match c.get_ref().trim() {
                "wall" => false,
                "sim" => true,
                other => {
                    self.err(
                        c.span(),
                        Some("clock".to_owned()),
                        LaunchErrorKind::InvalidValue(format!(
                            "clock {other:?}: expected \"wall\" or \"sim\""
                        )),
                    );
                    false
                }
            },
        };
        let checkpoint_dir = top.checkpoint_dir.as_ref().and_then(|d| {
            let text = d.get_ref().trim();
            if text.is_empty() {
                self.err(
                    d.span(),
                    Some("checkpoint_dir".to_owned()),
                    LaunchErrorKind::InvalidValue(
                        "checkpoint_dir must not be empty (leave it out for the default)"
                            .to_owned(),
                    ),
                );
                return None;
            }
            let p = Path::new(text);
            Some(if p.is_absolute() {
                p.to_owned()
            } else {
                self.file.parent().unwrap_or_else(|| Path::new(".")).join(p)
            })
        });

        let mut specs = Vec::new();
        let mut seen: HashMap<String, usize> = HashMap::new();
        let mut manager: Option<(String, usize)> = None;
        let mut spans = Vec::new();
        for (i, mut raw, span, table) in raws {
            let prefix = format!("module[{i}]");
            let name = raw.name.get_ref().clone();
            if !valid_name(&name) {
                self.err(
                    raw.name.span(),
                    Some(format!("{prefix}.name")),
                    LaunchErrorKind::InvalidValue(format!(
                        "module name {name:?} must be non-empty and use only A-Z, a-z, 0-9, '_' and '-'"
                    )),
                );
            }
            let name_line = self.line_of(raw.name.span().start);
            if let Some(first_line) = seen.get(&name) {
                let first_line = *first_line;
                self.err(
                    raw.name.span(),
                    Some(format!("{prefix}.name")),
                    LaunchErrorKind::DuplicateModule {
                        name: name.clone(),
                        first_line,
                    },
                );
            } else {
                seen.insert(name.clone(), name_line);
            }
            if let Some(m) = &raw.manager
                && *m.get_ref()
            {
                match &manager {
                    Some((first, first_line)) => {
                        let kind = LaunchErrorKind::TwoManagers {
                            first: first.clone(),
                            first_line: *first_line,
                        };
                        self.err(m.span(), Some(format!("{prefix}.manager")), kind);
                    }
                    None => manager = Some((name.clone(), self.line_of(m.span().start))),
                }
            }
            let settings = raw.take_settings();
            let merged = Merged {
                d: defaults,
                m: &settings,
                d_prefix: "defaults",
                m_prefix: prefix.clone(),
            };
            let program = self.resolve_program(&raw.command, &prefix, self_exe.as_deref(), opts);
            let resolved = program.is_some();
            let mut spec = ModuleSpec::new(name, program.unwrap_or_default(), &[]);
            spec.args = raw
                .command
                .get_ref()
                .iter()
                .skip(1)
                .map(|a| a.get_ref().clone())
                .collect();
            spec.manager = raw.manager.as_ref().is_some_and(|m| *m.get_ref());
            let names = |list: &Option<Vec<S<String>>>| -> Vec<String> {
                list.iter().flatten().map(|s| s.get_ref().clone()).collect()
            };
            spec.needs = names(&raw.needs);
            spec.provides = names(&raw.provides);
            self.apply_settings(&merged, &mut spec);
            if let Some(cfg) = &raw.config {
                match toml::to_string(cfg.get_ref()) {
                    Ok(text) => spec.config = text,
                    Err(e) => self.err(
                        cfg.span(),
                        Some(format!("{prefix}.config")),
                        LaunchErrorKind::InvalidValue(format!(
                            "the config table cannot be passed on as TOML: {e}"
                        )),
                    ),
                }
            }
            if resolved
                && let Some(check) = &opts.check_module
                && let Err(problem) = check(&spec)
            {
                self.module_problem(problem, &raw, table.as_ref(), &spec.config, &prefix);
            }
            specs.push(spec);
            spans.push((
                span,
                raw.needs.as_ref().and_then(|n| n.first().map(|s| s.span())),
            ));
        }

        let (order, warnings) = self.start_order(&specs, &spans);
        if !self.errors.is_empty() {
            return None;
        }
        let modules = order
            .into_iter()
            .filter_map(|i| specs.get(i).cloned())
            .collect();
        Some(LaunchPlan {
            file: self.file.to_owned(),
            system,
            modules,
            sim_clock,
            checkpoint_dir,
            warnings,
        })
    }

    pub(crate) fn resolve_program(
        &mut self,
        command: &S<Vec<S<String>>>,
        prefix: &str,
        self_exe: Option<&Path>,
        opts: &LoadOptions,
    ) -> Option<PathBuf> {
        let field = Some(format!("{prefix}.command"));
        let Some(first) = command.get_ref().first() else {
            self.err(
                command.span(),
                field,
                LaunchErrorKind::InvalidValue(
                    "command is empty: give the program and its arguments, e.g. [\"hng\", \"module\", \"slam\"]"
                        .to_owned(),
                ),
            );
            return None;
        };
        let program = first.get_ref();
        // The program's path, or why it is missing.
        let candidate = if program == "hng" || program == "@hng" {
            self_exe
                .map(Path::to_owned)
                .ok_or_else(|| "the path of the running executable is unknown".to_owned())
        } else if program.contains('/') {
            let p = Path::new(program);
            Ok(if p.is_absolute() {
                p.to_owned()
            } else {
                self.file.parent().unwrap_or_else(|| Path::new(".")).join(p)
            })
        } else {
            let path = opts
                .path
                .clone()
                .or_else(|| std::env::var_os("PATH"))
                .unwrap_or_default();
            let found = std::env::split_paths(&path)
                .map(|dir| dir.join(program))
                .find(|p| is_executable(p).is_ok());
            match found {
                Some(p) => Ok(p),
                None if !opts.check_binaries => Ok(PathBuf::from(program)),
                None => Err("not found in PATH (or not executable there)".to_owned()),
            }
        };
        let checked = candidate.and_then(|c| {
            if opts.check_binaries {
                is_executable(&c).map_err(|reason| format!("{}: {reason}", c.display()))?;
            }
            Ok(c)
        });
        match checked {
            Ok(c) => Some(c),
            Err(reason) => {
                self.err(
                    first.span(),
                    field,
                    LaunchErrorKind::MissingBinary {
                        program: program.clone(),
                        reason,
                    },
                );
                None
            }
        }
    }

    pub(crate) fn validate_settings_alone(&mut self, d: &RawSettings) {
        let none = RawSettings::default();
        let merged = Merged {
            d: &none,
            m: d,
            d_prefix: "defaults",
            m_prefix: "defaults".to_owned(),
        };
        let mut scratch = ModuleSpec::new("defaults", "", &[]);
        self.apply_settings(&merged, &mut scratch);
    }

    /// Topological order from needs/provides (stable: file order among ready
    /// modules). Reports cycles as errors and unprovided needs as warnings.
    pub(crate) fn start_order(
        &mut self,
        specs: &[ModuleSpec],
        spans: &[(std::ops::Range<usize>, Option<std::ops::Range<usize>>)],
    ) -> (Vec<usize>, Vec<String>) {
        let mut warnings = Vec::new();
        let mut providers: HashMap<&str, Vec<usize>> = HashMap::new();
        for (i, s) in specs.iter().enumerate() {
            for p in &s.provides {
                providers.entry(p.as_str()).or_default().push(i);
            }
        }
        // deps[i]: modules that must start before i.
        let mut deps: Vec<Vec<usize>> = vec![Vec::new(); specs.len()];
        for (i, s) in specs.iter().enumerate() {
            for n in &s.needs {
                match providers.get(n.as_str()) {
                    Some(ps) => deps[i].extend(ps.iter().copied().filter(|&p| p != i)),
                    None => warnings.push(format!(
                        "module {:?} needs {n:?} but no module provides it",
                        s.name
                    )),
                }
            }
        }
        let mut done = vec![false; specs.len()];
        let mut order = Vec::with_capacity(specs.len());
        while order.len() < specs.len() {
            let next = (0..specs.len()).find(|&i| !done[i] && deps[i].iter().all(|&d| done[d]));
            match next {
                Some(i) => {
                    done[i] = true;
                    order.push(i);
                }
                None => {
                    // Every remaining module waits on another: walk to a cycle.
                    let Some(start) = (0..specs.len()).find(|&i| !done[i]) else {
                        break;
                    };
                    let mut path = vec![start];
                    let mut cur = start;
                    let cycle = loop {
                        let Some(&next) = deps[cur].iter().find(|&&d| !done[d]) else {
                            break vec![cur];
                        };
                        if let Some(pos) = path.iter().position(|&p| p == next) {
                            let mut c = path.split_off(pos);
                            c.push(next);
                            break c;
                        }
                        path.push(next);
                        cur = next;
                    };
                    let names: Vec<String> = cycle.iter().map(|&i| specs[i].name.clone()).collect();
                    let first = cycle.first().copied().unwrap_or(start);
                    let (module_span, needs_span) = spans[first].clone();
                    self.err(
                        needs_span.unwrap_or(module_span),
                        Some(format!("module \"{}\".needs", specs[first].name)),
                        LaunchErrorKind::Cycle(names),
                    );
                    // Mark the cycle done and keep going, so every cycle is reported.
                    for &i in &cycle {
                        if !done[i] {
                            done[i] = true;
                            order.push(i);
                        }
                    }
                }
            }
        }
        (order, warnings)
    }
}

/// The innermost key of `table` (recursively) whose key or value span
/// contains `offset`. Sub-tables are searched first: the span of a `[table]`
/// value covers only its header, not its keys.
pub(crate) fn key_at(table: &DeTable<'_>, offset: usize) -> Option<String> {
    for (k, v) in table.iter() {
        if let DeValue::Table(inner) = v.get_ref()
            && let Some(sub) = key_at(inner, offset)
        {
            return Some(format!("{}.{sub}", k.get_ref()));
        }
    }
    table
        .iter()
        .find(|(k, v)| {
            let ks = k.span();
            ks.contains(&offset)
                || v.span().contains(&offset)
                || (ks.start == offset && ks.is_empty())
        })
        .map(|(k, _)| k.get_ref().to_string())
}

pub(crate) fn valid_name(name: &str) -> bool {
    !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
}

pub(crate) fn is_executable(p: &Path) -> Result<(), String> {
    match std::fs::metadata(p) {
        Err(e) => Err(e.to_string()),
        Ok(m) if !m.is_file() => Err("not a regular file".to_owned()),
        Ok(m) if m.permissions().mode() & 0o111 == 0 => {
            Err("not executable (no x permission)".to_owned())
        }
        Ok(_) => Ok(()),
    }
}
