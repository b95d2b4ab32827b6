//! `hng contracts [--json]`: the live contract tree (client, provider, service, priority, V)
//! and the data-exchange network (which channel flows from which provider to which client),
//! read from the contract tables every module publishes on `hng/contracts` (paper 5.8,
//! figures 3 and 4). `--follow` streams the switches instead (`contracts_follow.rs`).

use std::collections::{BTreeMap, BTreeSet};
use std::time::{Duration, Instant};

use anyhow::{Result, bail};
use hng_runtime::Node;
use hng_runtime::channel::Subscriber;
use hng_runtime::control::TABLE_PERIOD;
use hng_runtime::system::{CONTRACTS, ContractRole, ContractTable, SUPERVISOR_STATUS};
use hng_runtime::wait::Waiter;
use serde::Serialize;

/// Arguments of `hng contracts`.
#[derive(Debug, clap::Args)]
pub struct ContractsArgs {
    /// One JSON document (modules, contracts, data network) for tools.
    #[arg(long)]
    pub json: bool,
    /// How long to collect tables, in seconds (modules publish theirs every 200 ms).
    #[arg(long, default_value_t = 0.5)]
    pub wait: f64,
    /// Follow the contract switches: one line per provider made, switched or ended, until
    /// stopped (JSON lines with --json or when stdout is not a terminal).
    #[arg(long)]
    pub follow: bool,
}

#[derive(Debug, Serialize)]
struct ModuleView {
    name: String,
    id: u32,
    active: bool,
    priority: String,
    value: Option<f32>,
    control_drops: u64,
    protocol_drops: u64,
    commands_accepted: u64,
    commands_preempted: u64,
    commands_no_contract: u64,
}

#[derive(Debug, Serialize)]
struct ContractView {
    client: String,
    provider: String,
    service: String,
    need: u16,
    priority: String,
    value: f32,
    channel: String,
}

#[derive(Debug, Serialize)]
struct Flow {
    channel: String,
    from: String,
    to: String,
    service: String,
}

#[derive(Debug, Serialize)]
struct View {
    modules: Vec<ModuleView>,
    contracts: Vec<ContractView>,
    data: Vec<Flow>,
}

/// A reader of the contract tables every module publishes: the node (keep it alive), its
/// subscriber, and a waiter attached to it.
pub(crate) fn table_reader(prefix: &str) -> Result<(Node, Subscriber<ContractTable>, Waiter)> {
    crate::tool::reader(prefix, "contracts", CONTRACTS)
}

/// Collects the latest table of every module for `wait`.
pub fn collect(prefix: &str, wait: Duration) -> Result<BTreeMap<u32, ContractTable>> {
    let (_node, sub, mut waiter) = table_reader(prefix)?;
    let end = Instant::now() + wait;
    let mut tables = BTreeMap::new();
    loop {
        while let Some(t) = sub.receive()? {
            tables.insert(t.module_id, *t);
        }
        let left = end.saturating_duration_since(Instant::now());
        if left.is_zero() {
            break;
        }
        waiter.wait(Some(left))?;
    }
    Ok(tables)
}

fn view(tables: &BTreeMap<u32, ContractTable>) -> View {
    let name = |id: u32| {
        tables
            .get(&id)
            .map(|t| t.module().to_string())
            .unwrap_or_else(|| format!("m{id}"))
    };
    let modules = tables
        .values()
        .map(|t| ModuleView {
            name: t.module().to_string(),
            id: t.module_id,
            active: t.active != 0,
            priority: if t.active != 0 {
                hng_runtime::contract::dotted(t.priority())
            } else {
                "-".into()
            },
            value: t.value.is_finite().then_some(t.value),
            control_drops: t.control_drops,
            protocol_drops: t.protocol_drops,
            commands_accepted: t.commands_accepted,
            commands_preempted: t.commands_preempted,
            commands_no_contract: t.commands_no_contract,
        })
        .collect();
    let mut contracts = Vec::new();
    let mut data = Vec::new();
    for t in tables.values() {
        for e in t
            .entries()
            .iter()
            .filter(|e| e.role() == Some(ContractRole::Client))
        {
            contracts.push(ContractView {
                client: t.module().to_string(),
                provider: name(e.peer),
                service: e.service().to_string(),
                need: e.need,
                priority: hng_runtime::contract::dotted(e.priority()),
                value: e.value,
                channel: e.channel().to_string(),
            });
            if !e.channel().is_empty() {
                data.push(Flow {
                    channel: e.channel().to_string(),
                    from: name(e.peer),
                    to: t.module().to_string(),
                    service: e.service().to_string(),
                });
            }
        }
    }
    contracts.sort_by(|a, b| a.priority.cmp(&b.priority).then(a.client.cmp(&b.client)));
    View {
        modules,
        contracts,
        data,
    }
}

fn print_tree(
    tables: &BTreeMap<u32, ContractTable>,
    id: u32,
    depth: usize,
    seen: &mut BTreeSet<u32>,
) -> std::io::Result<()> {
    let Some(t) = tables.get(&id) else {
        return Ok(());
    };
    if !seen.insert(id) {
        return Ok(());
    }
    let mut entries: Vec<_> = t
        .entries()
        .iter()
        .filter(|e| e.role() == Some(ContractRole::Client))
        .collect();
    entries.sort_by_key(|e| e.need);
    for e in entries {
        let provider = tables
            .get(&e.peer)
            .map(|p| p.module().to_string())
            .unwrap_or_else(|| format!("m{}", e.peer));
        outln!(
            "{:indent$}{} [{}] -> {} (V {:.2})",
            "",
            e.service(),
            hng_runtime::contract::dotted(e.priority()),
            provider,
            e.value,
            indent = 2 * (depth + 1)
        )?;
        print_tree(tables, e.peer, depth + 1, seen)?;
    }
    seen.remove(&id);
    Ok(())
}

/// `hng contracts`.
pub fn run(prefix: &str, args: &ContractsArgs) -> Result<()> {
    let wait = Duration::try_from_secs_f64(args.wait.max(0.0))
        .unwrap_or(TABLE_PERIOD)
        .max(Duration::from_millis(1));
    // Asked without creating any file of the prefix: a read-only command leaves nothing.
    let has_tables = crate::top::channel_exists(prefix, CONTRACTS)?;
    let has_system = has_tables
        || hng_supervisor::lock::running_supervisor(prefix).is_some()
        || crate::top::channel_exists(prefix, SUPERVISOR_STATUS)?;
    if !has_system {
        bail!(
            "no hng system runs under prefix {prefix:?} (no supervisor, no contract tables); start one with `hng run` or pass --prefix"
        );
    }
    if args.follow {
        if !has_tables {
            bail!(
                "no contract tables on prefix {prefix:?} yet (no module with contracts running?)"
            );
        }
        return crate::contracts_follow::follow(prefix, args.json);
    }
    let tables = if has_tables {
        collect(prefix, wait)?
    } else {
        BTreeMap::new()
    };
    let v = view(&tables);
    if args.json {
        outln!("{}", serde_json::to_string_pretty(&v)?)?;
        return Ok(());
    }
    if tables.is_empty() {
        outln!("no contract tables on prefix {prefix:?} (no module with contracts running?)")?;
        return Ok(());
    }
    outln!("contract tree:")?;
    let roots: Vec<u32> = tables
        .values()
        .filter(|t| t.active != 0 && t.priority().is_empty())
        .map(|t| t.module_id)
        .collect();
    for r in &roots {
        outln!("{} (root)", tables[r].module())?;
        print_tree(&tables, *r, 0, &mut BTreeSet::new())?;
    }
    outln!("\ndata network:")?;
    for f in &v.data {
        outln!(
            "  {} -> {}  on {}  ({})",
            f.from,
            f.to,
            f.channel,
            f.service
        )?;
    }
    outln!("\nmodules:")?;
    outln!(
        "  {:<20} {:>8} {:>10} {:>7} {:>6} {:>6}",
        "name",
        "active",
        "priority",
        "V",
        "drops",
        "cmd_nc"
    )?;
    for m in &v.modules {
        outln!(
            "  {:<20} {:>8} {:>10} {:>7} {:>6} {:>6}",
            m.name,
            m.active,
            m.priority,
            m.value.map_or("-".into(), |v| format!("{v:.2}")),
            m.control_drops,
            m.commands_no_contract
        )?;
    }
    Ok(())
}
