//! Latency statistics and the output format of `hng bench`.
//!
//! Every benchmark prints, per case, one JSON object per line with at least `bench`, `case`,
//! `p50_ns`, `p99_ns`, `p999_ns`, `max_ns`, `samples`, plus its own fields; without `--json`,
//! a readable table.

use serde_json::{Map, Value};

/// Percentiles of a set of samples, in nanoseconds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct Percentiles {
    /// Median.
    pub p50_ns: u64,
    /// 99th percentile.
    pub p99_ns: u64,
    /// 99.9th percentile.
    pub p999_ns: u64,
    /// Largest.
    pub max_ns: u64,
    /// Number of samples.
    pub samples: u64,
}

impl Percentiles {
    /// Computes percentiles (nearest rank) of `samples`; sorts them in place.
    pub fn of(samples: &mut [u64]) -> Percentiles {
        if samples.is_empty() {
            return Percentiles::default();
        }
        samples.sort_unstable();
        let n = samples.len();
        let rank = |q: f64| samples[(((q * n as f64).ceil() as usize).max(1) - 1).min(n - 1)];
        Percentiles {
            p50_ns: rank(0.50),
            p99_ns: rank(0.99),
            p999_ns: rank(0.999),
            max_ns: samples[n - 1],
            samples: n as u64,
        }
    }
}

/// One result row of a benchmark.
#[derive(Debug, Clone)]
pub struct BenchRow {
    fields: Map<String, Value>,
}

impl BenchRow {
    /// A row for `bench`/`case` with the given percentiles.
    pub fn new(bench: &str, case: &str, p: Percentiles) -> BenchRow {
        let mut fields = Map::new();
        fields.insert("bench".into(), bench.into());
        fields.insert("case".into(), case.into());
        fields.insert("p50_ns".into(), p.p50_ns.into());
        fields.insert("p99_ns".into(), p.p99_ns.into());
        fields.insert("p999_ns".into(), p.p999_ns.into());
        fields.insert("max_ns".into(), p.max_ns.into());
        fields.insert("samples".into(), p.samples.into());
        BenchRow { fields }
    }

    /// Adds a field.
    #[must_use]
    pub fn with(mut self, key: &str, value: impl Into<Value>) -> BenchRow {
        self.fields.insert(key.into(), value.into());
        self
    }

    /// A field's value.
    pub fn get(&self, key: &str) -> Option<&Value> {
        self.fields.get(key)
    }

    /// The row as one line of JSON.
    pub fn to_json(&self) -> String {
        Value::Object(self.fields.clone()).to_string()
    }
}

fn cell(v: &Value) -> String {
    match v {
        Value::String(s) => s.clone(),
        Value::Number(n) => match (n.as_u64(), n.as_f64()) {
            (Some(u), _) => u.to_string(),
            (None, Some(f)) => format!("{f:.3}"),
            _ => n.to_string(),
        },
        other => other.to_string(),
    }
}

/// Renders rows as an aligned text table (columns in first-seen order).
pub fn table(rows: &[BenchRow]) -> String {
    let mut cols: Vec<String> = Vec::new();
    for r in rows {
        for k in r.fields.keys() {
            if !cols.contains(k) {
                cols.push(k.clone());
            }
        }
    }
    let cells: Vec<Vec<String>> = rows
        .iter()
        .map(|r| {
            cols.iter()
                .map(|c| r.fields.get(c).map(cell).unwrap_or_default())
                .collect()
        })
        .collect();
    let widths: Vec<usize> = cols
        .iter()
        .enumerate()
        .map(|(i, c)| {
            cells
                .iter()
                .map(|r| r[i].len())
                .chain([c.len()])
                .max()
                .unwrap_or(0)
        })
        .collect();
    let mut out = String::new();
    let line = |vals: &[String], out: &mut String| {
        let parts: Vec<String> = vals
            .iter()
            .zip(&widths)
            .map(|(v, w)| format!("{v:>w$}"))
            .collect();
        out.push_str(parts.join("  ").trim_end());
        out.push('\n');
    };
    line(&cols, &mut out);
    for r in &cells {
        line(r, &mut out);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_use_nearest_rank() {
        let mut s: Vec<u64> = (1..=1000).rev().collect();
        let p = Percentiles::of(&mut s);
        assert_eq!(p.p50_ns, 500);
        assert_eq!(p.p99_ns, 990);
        assert_eq!(p.p999_ns, 999);
        assert_eq!(p.max_ns, 1000);
        assert_eq!(p.samples, 1000);
        assert_eq!(Percentiles::of(&mut []), Percentiles::default());
    }

    #[test]
    fn rows_render_as_json_and_table() {
        let mut s = vec![10, 20, 30];
        let row = BenchRow::new("ipc", "hng/64/spin", Percentiles::of(&mut s)).with("size", 64);
        let v: Value = serde_json::from_str(&row.to_json()).expect("valid json");
        assert_eq!(v["bench"], "ipc");
        assert_eq!(v["p50_ns"], 20);
        assert_eq!(v["size"], 64);
        let t = table(&[row]);
        assert!(t.lines().next().is_some_and(|l| l.contains("p50_ns")));
        assert!(t.contains("hng/64/spin"));
    }
}
