//! `hng contracts --follow [--json]`: the contract switches as a stream, one line per change,
//! as the operator page's timeline shows them (docs/operator.md): a client's need gets a
//! provider (`made`), changes provider (`switch`), or loses it (`ended`). Read from the
//! contract tables every module publishes on `hng/contracts` (complete, every 200 ms), stamped
//! with the table's time (simulated time under `clock = "sim"`). In a terminal one readable
//! line per change; otherwise (or with `--json`) one JSON object per line.

use std::collections::BTreeMap;
use std::io::IsTerminal as _;
use std::time::{Duration, Instant};

use anyhow::Result;
use hng_runtime::control::TABLE_PERIOD;
use hng_runtime::system::{ContractRole, ContractTable};
use serde::Serialize;

/// One change of a client's provider.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Switch {
    /// Time of the client's table that shows it, s.
    pub t_s: f64,
    /// `made`, `switch` or `ended`.
    pub kind: &'static str,
    /// The client module.
    pub client: String,
    /// The service.
    pub service: String,
    /// The client's need rank.
    pub need: u16,
    /// The contract's priority (`2.5.2`), empty once ended.
    pub priority: String,
    /// The provider before (none for `made`).
    pub from: Option<String>,
    /// The provider now (none for `ended`).
    pub to: Option<String>,
    /// The new provider's value V as the client last heard it.
    pub value: Option<f32>,
}

impl Switch {
    /// The readable line.
    pub fn text(&self) -> String {
        let prio = if self.priority.is_empty() {
            String::new()
        } else {
            format!(" [{}]", self.priority)
        };
        let v = self.value.map_or(String::new(), |v| format!(" (V {v:.2})"));
        format!(
            "[{:8.2} s] {} {}{prio}: {} -> {}{v}{}",
            self.t_s,
            self.client,
            self.service,
            self.from.as_deref().unwrap_or("none"),
            self.to.as_deref().unwrap_or("none"),
            if self.kind == "switch" {
                String::new()
            } else {
                format!(" ({})", self.kind)
            }
        )
    }
}

/// The providers of every client's needs, from the tables seen; finds the changes.
#[derive(Debug, Default)]
pub struct SwitchLog {
    names: BTreeMap<u32, String>,
    /// (client, need) -> (provider, service).
    holders: BTreeMap<(u32, u16), (u32, String)>,
}

impl SwitchLog {
    /// Learns a module's name without looking at its contracts.
    pub fn learn(&mut self, t: &ContractTable) {
        self.names.insert(t.module_id, t.module().to_owned());
    }

    fn name(&self, id: u32) -> String {
        self.names
            .get(&id)
            .cloned()
            .unwrap_or_else(|| format!("m{id}"))
    }

    /// The changes `t` (a client's complete table) shows against what was seen before.
    pub fn on_table(&mut self, t: &ContractTable) -> Vec<Switch> {
        self.learn(t);
        let t_s = t.header.stamp_ns as f64 * 1e-9;
        let client = t.module_id;
        let mut out = Vec::new();
        let mut now = BTreeMap::new();
        for e in t
            .entries()
            .iter()
            .filter(|e| e.role() == Some(ContractRole::Client))
        {
            now.insert(e.need, e.peer);
            let before = self.holders.get(&(client, e.need)).map(|h| h.0);
            if before == Some(e.peer) {
                continue;
            }
            out.push(Switch {
                t_s,
                kind: if before.is_some() { "switch" } else { "made" },
                client: t.module().to_owned(),
                service: e.service().to_owned(),
                need: e.need,
                priority: hng_runtime::contract::dotted(e.priority()),
                from: before.map(|b| self.name(b)),
                to: Some(self.name(e.peer)),
                value: e.value.is_finite().then_some(e.value),
            });
            self.holders
                .insert((client, e.need), (e.peer, e.service().to_owned()));
        }
        let ended: Vec<(u16, u32, String)> = self
            .holders
            .range((client, 0)..=(client, u16::MAX))
            .filter(|((_, need), _)| !now.contains_key(need))
            .map(|((_, need), (p, s))| (*need, *p, s.clone()))
            .collect();
        for (need, p, service) in ended {
            self.holders.remove(&(client, need));
            out.push(Switch {
                t_s,
                kind: "ended",
                client: t.module().to_owned(),
                service,
                need,
                priority: String::new(),
                from: Some(self.name(p)),
                to: None,
                value: None,
            });
        }
        out
    }
}

/// `hng contracts --follow`: prints every change until stopped (Ctrl-C).
pub fn follow(prefix: &str, json: bool) -> Result<()> {
    let (_node, sub, mut waiter) = crate::contracts::table_reader(prefix)?;
    let json = json || !std::io::stdout().is_terminal();
    let mut log = SwitchLog::default();
    // First every module's name (two table periods), so the first lines name the providers.
    let names_until = Instant::now() + 2 * TABLE_PERIOD + Duration::from_millis(100);
    let mut first = Vec::new();
    loop {
        while let Some(t) = sub.receive()? {
            log.learn(&t);
            first.push(*t);
        }
        let left = names_until.saturating_duration_since(Instant::now());
        if left.is_zero() {
            break;
        }
        waiter.wait(Some(left))?;
    }
    let print = |log: &mut SwitchLog, t: &ContractTable| -> Result<()> {
        for s in log.on_table(t) {
            if json {
                outln!("{}", serde_json::to_string(&s)?)?;
            } else {
                outln!("{}", s.text())?;
            }
        }
        Ok(())
    };
    for t in &first {
        print(&mut log, t)?;
    }
    loop {
        while let Some(t) = sub.receive()? {
            print(&mut log, &t)?;
        }
        waiter.wait(Some(Duration::from_secs(1)))?;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use hng_runtime::system::ContractEntry;

    fn table(name: &str, stamp_s: f64, entries: &[(u16, &str, &str)]) -> ContractTable {
        let mut t = ContractTable {
            module_id: hng_runtime::msg::module_id(name),
            count: entries.len() as u32,
            ..ContractTable::default()
        };
        t.module[..name.len()].copy_from_slice(name.as_bytes());
        t.header.stamp_ns = (stamp_s * 1e9) as u64;
        for (i, (need, service, peer)) in entries.iter().enumerate() {
            let mut e = ContractEntry {
                role: ContractRole::Client as u8,
                peer: hng_runtime::msg::module_id(peer),
                need: *need,
                value: 0.5,
                ..ContractEntry::default()
            };
            e.service[..service.len()].copy_from_slice(service.as_bytes());
            t.entries[i] = e;
        }
        t
    }

    #[test]
    fn a_provider_made_switched_and_ended_is_one_line_each() {
        let mut log = SwitchLog::default();
        for n in ["tracker_colour", "tracker_histogram"] {
            log.learn(&table(n, 0.0, &[]));
        }
        let made = log.on_table(&table(
            "reacher",
            1.0,
            &[(2, "Track beacon", "tracker_colour")],
        ));
        assert_eq!(made.len(), 1);
        assert_eq!(made[0].kind, "made");
        assert_eq!(made[0].to.as_deref(), Some("tracker_colour"));
        assert!(
            log.on_table(&table(
                "reacher",
                1.2,
                &[(2, "Track beacon", "tracker_colour")]
            ))
            .is_empty(),
            "no change, no line"
        );
        let sw = log.on_table(&table(
            "reacher",
            3.6,
            &[(2, "Track beacon", "tracker_histogram")],
        ));
        assert_eq!(sw.len(), 1);
        let s = &sw[0];
        assert_eq!((s.kind, s.t_s), ("switch", 3.6));
        assert_eq!(s.from.as_deref(), Some("tracker_colour"));
        assert_eq!(s.to.as_deref(), Some("tracker_histogram"));
        assert!(
            s.text().contains("reacher Track beacon")
                && s.text().contains("tracker_colour -> tracker_histogram"),
            "{}",
            s.text()
        );
        let json = serde_json::to_string(s).unwrap_or_default();
        assert!(json.contains(r#""kind":"switch""#), "{json}");
        let ended = log.on_table(&table("reacher", 5.0, &[]));
        assert_eq!(ended.len(), 1);
        assert_eq!(ended[0].kind, "ended");
        assert_eq!(ended[0].service, "Track beacon");
        assert_eq!(ended[0].to, None);
    }
}
