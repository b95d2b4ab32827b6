//! Where in a TOML document a field is written: errors of `serde`/`toml` and of
//! [`World::validate`](super::World::validate) name the file's line, column and field.

/// The text between `prefix` and the next backtick in `message`.
pub(super) fn backticked<'a>(message: &'a str, prefix: &str) -> Option<&'a str> {
    let start = message.find(prefix)? + prefix.len();
    let rest = message.get(start..)?;
    rest.find('`').and_then(|end| rest.get(..end))
}

pub(super) fn join_field(table: &str, key: &str) -> String {
    match (table.is_empty(), key.is_empty()) {
        (true, _) => key.to_owned(),
        (_, true) => table.to_owned(),
        _ => format!("{table}.{key}"),
    }
}

/// Tracks `[table]` and `[[array]]` headers line by line, giving paths like `walls[2]`.
#[derive(Default)]
struct HeaderTracker {
    current: String,
    counts: std::collections::HashMap<String, usize>,
}

impl HeaderTracker {
    /// Updates the current table if `line` is a header; returns whether it was one.
    fn feed(&mut self, line: &str) -> bool {
        let t = line.trim();
        if let Some(inner) = t.strip_prefix("[[").and_then(|r| r.split("]]").next()) {
            let name = inner.trim().to_owned();
            // A nested array like [[sensors.gps.zones]] counts within its parent.
            let n = self.counts.entry(name.clone()).or_insert(0);
            self.current = format!("{name}[{}]", *n);
            *n += 1;
            true
        } else if let Some(inner) = t.strip_prefix('[').and_then(|r| r.split(']').next()) {
            self.current = inner.trim().to_owned();
            true
        } else {
            false
        }
    }
}

/// Dotted path of the key being defined at byte `offset` of a TOML document.
pub(super) fn toml_field_at(src: &str, offset: usize) -> String {
    let mut tracker = HeaderTracker::default();
    let mut pos = 0;
    for line in src.split_inclusive('\n') {
        let end = pos + line.len();
        if offset < end || end == src.len() {
            if tracker.feed(line) {
                return tracker.current;
            }
            let col = offset.saturating_sub(pos).min(line.len());
            let prefix = line.get(..col).unwrap_or(line);
            let keys = inline_keys(prefix);
            let key = if keys.is_empty() {
                // The offset is on the key itself, e.g. an unknown field.
                line.split('=')
                    .next()
                    .unwrap_or("")
                    .trim()
                    .trim_matches('"')
                    .to_owned()
            } else {
                keys.join(".")
            };
            return join_field(&tracker.current, &key);
        }
        tracker.feed(line);
        pos = end;
    }
    tracker.current
}

/// Keys open at the end of a TOML line prefix: `a = { b = [1, { c = ` gives [a, b, c].
pub(super) fn inline_keys(prefix: &str) -> Vec<String> {
    let mut stack: Vec<String> = Vec::new();
    let mut pending: Option<String> = None;
    let mut word = String::new();
    let mut last_word = String::new();
    let mut in_str = false;
    for ch in prefix.chars() {
        if in_str {
            if ch == '"' || ch == '\'' {
                in_str = false;
            }
            continue;
        }
        match ch {
            '"' | '\'' => in_str = true,
            '#' => break,
            '=' => {
                if let Some(p) = pending.take() {
                    stack.push(p);
                }
                pending = Some(std::mem::take(&mut last_word));
            }
            '{' | '[' => {
                if let Some(p) = pending.take() {
                    stack.push(p);
                }
                stack.push(String::new());
            }
            '}' | ']' => {
                pending = None;
                while let Some(top) = stack.pop() {
                    if top.is_empty() {
                        break;
                    }
                }
                // The key owning the closed value is complete too.
                stack.pop();
            }
            ',' => pending = None,
            c if c.is_alphanumeric() || c == '_' || c == '-' => word.push(c),
            _ => {}
        }
        let in_word = ch.is_alphanumeric() || ch == '_' || ch == '-';
        if !in_word && !word.is_empty() {
            last_word = std::mem::take(&mut word);
        }
    }
    stack
        .into_iter()
        .chain(pending)
        .filter(|k| !k.is_empty())
        .collect()
}

/// 1-based line and column where `field` (as produced by `validate`) is written, or of its
/// nearest enclosing table; (1, 1) if nothing matches.
pub(super) fn locate_toml_field(src: &str, field: &str) -> (usize, usize) {
    let mut tracker = HeaderTracker::default();
    let mut best: Option<(usize, usize, usize)> = None; // (score, line, column)
    for (i, line) in src.lines().enumerate() {
        let path = if tracker.feed(line) {
            tracker.current.clone()
        } else {
            let t = line.trim_start();
            if t.starts_with('#') || !t.contains('=') {
                continue;
            }
            let key = t.split('=').next().unwrap_or("").trim().trim_matches('"');
            join_field(&tracker.current, key)
        };
        let matches = field == path
            || field.starts_with(&format!("{path}."))
            || field.starts_with(&format!("{path}["));
        if matches && best.is_none_or(|(score, _, _)| path.len() > score) {
            let column = line.len() - line.trim_start().len() + 1;
            best = Some((path.len(), i + 1, column));
        }
    }
    best.map_or((1, 1), |(_, l, c)| (l, c))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inline_keys_follow_nesting() {
        assert_eq!(inline_keys("start = { x = 1.0, y = "), vec!["start", "y"]);
        assert_eq!(inline_keys("beams = "), vec!["beams"]);
        assert_eq!(inline_keys("a = { b = [1, 2], c = "), vec!["a", "c"]);
    }

    #[test]
    fn locate_finds_array_of_tables_entries() {
        let src = "[robot]\nstart = { x = 1, y = 2 }\n[[walls]]\nfrom = [0, 0]\n[[walls]]\nfrom = [1, 1]\nthickness = -1\n";
        assert_eq!(locate_toml_field(src, "walls[1].thickness"), (7, 1));
        assert_eq!(locate_toml_field(src, "walls[0].thickness"), (3, 1));
        assert_eq!(locate_toml_field(src, "robot.start.x"), (2, 1));
    }
}
