//! The control plane's traffic: what it reads from the system (the supervisor's events, the
//! RM's costs) and from its peers (its inbox and the services it provides), the peers it
//! discovers, and the agent's messages it sends.

use super::*;

impl ControlPlane {
    /// Reads the supervisor's events and the RM's costs; true when the agent's inputs changed
    /// (it must be ticked).
    pub(super) fn read_system(&mut self, now: Duration, out: &mut Vec<Outgoing>) -> bool {
        let mut changed = false;
        loop {
            match self.events.receive() {
                Ok(Some(e)) => {
                    if matches!(
                        e.kind(),
                        Some(EventKind::Died | EventKind::Deactivated | EventKind::Stopped)
                    ) && e.module_id != self.agent.id().0
                    {
                        out.extend(self.agent.module_died(ModuleId(e.module_id), now));
                        changed = true;
                    }
                }
                Ok(None) => break,
                Err(e) => {
                    tracing::debug!(module = %self.name, "supervisor events: {e}");
                    break;
                }
            }
        }
        let mut costs: Option<Sample<ResourceCosts>> = None;
        while let Ok(Some(c)) = self.costs.receive() {
            costs = Some(c);
        }
        if let Some(c) = costs {
            changed = true;
            self.cost = ResourceVec::new(c.cpu, c.mem, c.comm);
            self.agent.set_resources(self.r_eff, self.cost);
            let min = if c.degraded != 0 {
                c.min_priority().and_then(|p| Priority::new(p).ok())
            } else {
                None
            };
            self.agent.set_min_priority(min);
            self.agent.set_lacking_resources(c.serve_nothing != 0);
        }
        let mut eff: Option<Sample<EffectiveCosts>> = None;
        while let Ok(Some(c)) = self.effective.receive() {
            eff = Some(c);
        }
        if let Some(c) = eff
            && let Some(m) = c.of(self.agent.id().0)
        {
            changed = true;
            self.r_eff = ResourceVec::new(m.effective[0], m.effective[1], m.effective[2]);
            self.agent.set_resources(self.r_eff, self.cost);
        }
        changed
    }

    /// Reads the control messages and hands them to the agent; true if there were any (the
    /// agent then also did what was due).
    pub(super) fn read_control(&mut self, now: Duration, out: &mut Vec<Outgoing>) -> bool {
        let mut batch = Vec::new();
        let subs = std::iter::once(&self.inbox).chain(self.queries.iter());
        for sub in subs {
            loop {
                let sample = match sub.receive() {
                    Ok(Some(s)) => s,
                    Ok(None) => break,
                    Err(e) => {
                        tracing::debug!(module = %self.name, "control input: {e}");
                        break;
                    }
                };
                match contract::decode(sample.data()) {
                    Ok(env) if env.from.0 != sample.header().header.source => {
                        self.drops.record(DropReason::Spoofed);
                    }
                    Ok(env) => {
                        tracing::trace!(module = %self.name, from = %env.from, msg = ?env.body, "contract receive");
                        batch.push(env);
                    }
                    Err(e) => {
                        tracing::debug!(module = %self.name, "control message dropped: {e}");
                        self.drops.record_error(&e);
                    }
                }
            }
        }
        if batch.is_empty() {
            return false;
        }
        out.extend(self.agent.handle_all(&batch, now));
        true
    }

    /// Opens publishers to the inboxes of the modules already running when this one starts,
    /// so the first message to them does not pay for opening a channel (a few ms, more on a
    /// loaded machine) on the protocol's critical path. Done once: listing the services reads
    /// every service's description, too costly to repeat periodically in every module; peers
    /// that start later are opened on first use.
    pub(super) fn discover_peers(&mut self, node: &Node) {
        let started = std::time::Instant::now();
        let prefix = format!("{CONTROL_ROOT}/m");
        let own = inbox_channel(self.agent.id());
        let mut found = Vec::new();
        let _ = <crate::channel::Service as iceoryx2::service::Service>::list(
            node.iceoryx_config(),
            |d| {
                let name = d.static_details.name().to_string();
                if let Some(id) = name.strip_prefix(&prefix)
                    && name != own
                    && let Ok(id) = id.parse::<u32>()
                {
                    found.push(ModuleId(id));
                }
                iceoryx2::prelude::CallbackProgression::Continue
            },
        );
        for id in found {
            if self.to_modules.contains_key(&id) {
                continue;
            }
            match node.slice_publisher::<ControlInfo>(&inbox_channel(id), MAX_MESSAGE_LEN) {
                Ok(p) => {
                    self.to_modules.insert(id, p);
                }
                Err(e) => tracing::debug!(module = %self.name, "peer {id}: {e}"),
            }
        }
        tracing::debug!(
            module = %self.name,
            peers = self.to_modules.len(),
            ms = started.elapsed().as_secs_f64() * 1e3,
            "peers' inboxes opened"
        );
    }

    pub(super) fn dispatch(&mut self, node: &Node, mut out: Vec<Outgoing>, now: Duration) {
        // A reply may make more messages due (e.g. a call closing once all providers
        // answered); bounded rounds keep a misbehaving peer from looping us.
        for _ in 0..4 {
            if out.is_empty() {
                break;
            }
            for o in out.drain(..) {
                self.send(node, &o);
            }
            self.collect_events();
            out = self.agent.tick(now);
        }
        for o in out {
            self.send(node, &o);
        }
        self.collect_events();
    }

    pub(super) fn send(&mut self, node: &Node, o: &Outgoing) {
        tracing::trace!(module = %self.name, to = ?o.to, msg = ?o.envelope.body, "contract send");
        let bytes = match contract::encode(&o.envelope) {
            Ok(b) => b,
            Err(e) => {
                tracing::warn!(module = %self.name, "contract message not sent: {e}");
                self.drops.record_error(&e);
                return;
            }
        };
        // In lockstep, a heartbeat that says nothing new calls none of its readers.
        let _quiet = self.repeats.repeated(o).then(|| node.unannounced());
        let result = match &o.to {
            Destination::Module(id) => {
                if !self.to_modules.contains_key(id) {
                    match node.slice_publisher::<ControlInfo>(&inbox_channel(*id), MAX_MESSAGE_LEN)
                    {
                        Ok(p) => {
                            self.to_modules.insert(*id, p);
                        }
                        Err(e) => {
                            self.send_failed(&e);
                            return;
                        }
                    }
                }
                match self.to_modules.get(id) {
                    Some(p) => p.publish_copy(ControlInfo::default(), &bytes),
                    None => return,
                }
            }
            Destination::Providers(service) => {
                if !self.to_services.contains_key(service) {
                    match open_service_out(node, service) {
                        Ok(s) => {
                            self.to_services.insert(service.clone(), s);
                        }
                        Err(e) => {
                            self.send_failed(&e);
                            return;
                        }
                    }
                }
                match self.to_services.get(service) {
                    Some(s) => {
                        let n = provider_count(&self.agent, service, s);
                        self.agent.set_provider_count(service, n);
                        s.publisher.publish_copy(ControlInfo::default(), &bytes)
                    }
                    None => return,
                }
            }
        };
        if let Err(e) = result {
            self.send_failed(&e);
        }
    }

    pub(super) fn send_failed(&mut self, e: &Error) {
        self.send_failures += 1;
        tracing::warn!(module = %self.name, "contract message not sent: {e}");
    }
}

pub(super) fn open_service_out(node: &Node, service: &str) -> Result<ServiceOut, Error> {
    let channel = service_channel(service);
    let publisher = node.slice_publisher::<ControlInfo>(&channel, MAX_MESSAGE_LEN)?;
    let name = ServiceName::new(&channel).map_err(|e| Error::InvalidChannelName {
        channel: channel.clone(),
        reason: format!("{e:?}"),
    })?;
    let factory = node
        .iceoryx()
        .service_builder(&name)
        .publish_subscribe::<[u8]>()
        .user_header::<ControlInfo>()
        .open()
        .map_err(|e| Error::Channel {
            channel: channel.clone(),
            op: "open",
            detail: format!("{e:?}"),
        })?;
    Ok(ServiceOut { publisher, factory })
}
