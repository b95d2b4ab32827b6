//! Scenario and property tests of the contract protocol.

mod dwell;
mod props;
mod scenarios;
mod switch;

use std::time::Duration;

use super::sim::{Sim, SimConfig};
use super::{AgentConfig, ContractAgent, ModuleId, NeedSpec, ServiceOffer};

pub(crate) fn ms(v: u64) -> Duration {
    Duration::from_millis(v)
}

/// Builds a provider module.
pub(crate) fn module(id: u32, q: f64, provides: &[&str], needs: &[(&str, u16)]) -> ContractAgent {
    let mut cfg = AgentConfig::new(ModuleId(id));
    for s in provides {
        cfg = cfg.provide(ServiceOffer::new(*s, format!("{s} data")));
    }
    for (s, rank) in needs {
        cfg = cfg.need(NeedSpec::required(*s, *rank));
    }
    let mut a = ContractAgent::new(cfg).unwrap();
    a.set_quality(q);
    a
}

pub(crate) fn manager(id: u32, objectives: &[&str]) -> ContractAgent {
    ContractAgent::new(AgentConfig::manager(ModuleId(id), objectives)).unwrap()
}

pub(crate) fn sim() -> Sim {
    Sim::new(SimConfig::default())
}
