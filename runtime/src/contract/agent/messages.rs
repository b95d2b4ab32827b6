//! The agent's state machine, message side: every protocol message in, what it answers.

use std::time::Duration;

use super::*;

impl ContractAgent {
    // ----- the state machine -----

    /// Periodic work: deadlines, refreshes, value reports, timeouts, probes.
    /// Call it often (e.g. every 10 ms); it only acts on what is due.
    pub fn tick(&mut self, now: Duration) -> Vec<Outgoing> {
        let mut out = Vec::new();
        self.step(now, &mut out);
        out
    }

    /// Handles one incoming message, then does what is due at `now`.
    pub fn handle(&mut self, env: &Envelope, now: Duration) -> Vec<Outgoing> {
        self.handle_all(std::slice::from_ref(env), now)
    }

    /// Handles every message of a batch (all that arrived since the last wake-up), then
    /// does what is due at `now` once. A transport that was descheduled past a reply
    /// deadline thus still counts the replies that arrived before it ran again.
    pub fn handle_all(&mut self, envs: &[Envelope], now: Duration) -> Vec<Outgoing> {
        let mut out = Vec::new();
        for env in envs {
            self.receive(env, now, &mut out);
        }
        self.step(now, &mut out);
        out
    }

    pub(super) fn receive(&mut self, env: &Envelope, now: Duration, out: &mut Vec<Outgoing>) {
        let from = env.from;
        if from == self.cfg.id {
            self.drops.record(DropReason::FromSelf);
            return;
        }
        match &env.body {
            Message::Query(q) => self.on_query(from, q, now, out),
            Message::Propose(p) => self.on_propose(from, p),
            Message::Refuse(r) => self.on_refuse(from, r),
            Message::Accept(a) => self.on_accept(from, a, now, out),
            Message::Reject(_) => {}
            Message::Cancel(c) => self.on_cancel(from, c, now, out),
            Message::BetterOffer(b) => self.on_better_offer(from, b, now, out),
            Message::Feedback(f) => match self.clients.get_mut(&(from, f.need)) {
                Some(c) => {
                    c.last_heard = now;
                    self.feedback.record(f64::from(f.evaluation), now);
                }
                None => self.drops.record(DropReason::UnknownContract),
            },
            Message::Value(v) => self.on_value(from, v, now, out),
            Message::Update(u) => self.on_update(from, u, now, out),
        }
    }

    pub(super) fn offer_for(&self, service: &str) -> Option<&ServiceOffer> {
        self.cfg.provides.iter().find(|o| o.service == service)
    }

    /// Can this module serve `client` for `service` at `priority` with the
    /// client's `lineage`? Returns the value to propose.
    pub(super) fn can_serve(
        &self,
        client: ModuleId,
        service: &str,
        priority: Option<Priority>,
        lineage: &[ModuleId],
        existing: bool,
        now: Duration,
    ) -> Result<f64, Reason> {
        if self.offer_for(service).is_none() {
            return Err(Reason::NotProvided);
        }
        let value = self.value(now).map_err(|_| Reason::Inactive)?;
        if client == self.cfg.id || lineage.binary_search(&self.cfg.id).is_ok() {
            return Err(Reason::Cycle);
        }
        if self.known_unmet {
            return Err(Reason::NeedsUnmet);
        }
        if self.lacking_resources {
            return Err(Reason::NoResources);
        }
        if let (Some(min), Some(p)) = (self.min_priority, priority)
            && !p.admitted_by(&min)
        {
            return Err(Reason::Degraded);
        }
        if let Some(p) = priority
            && p.len() >= MAX_DEPTH
            && !self.needs.is_empty()
        {
            return Err(Reason::TooDeep);
        }
        if sorted_union(&self.lineage, lineage).len() > MAX_LINEAGE {
            return Err(Reason::TooDeep);
        }
        if !existing && self.clients.len() >= self.cfg.max_clients {
            return Err(Reason::Overloaded);
        }
        Ok(value)
    }

    pub(super) fn channel_for(&self, service: &str) -> String {
        self.offer_for(service)
            .map(|o| o.channel_for(self.cfg.id))
            .unwrap_or_default()
    }

    pub(super) fn on_query(
        &mut self,
        from: ModuleId,
        q: &Query,
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        let id = self.cfg.id;
        let key = (from, q.need);
        if q.kind == QueryKind::Refresh {
            let selected_is_me = q.selected.is_some_and(|s| s.provider == id);
            if selected_is_me {
                match self.clients.get_mut(&key) {
                    Some(c) => {
                        c.last_heard = now;
                        if let Some(e) = q.feedback {
                            self.feedback.record(f64::from(e), now);
                        }
                    }
                    None => {
                        // The client believes in a contract we do not hold.
                        self.drops.record(DropReason::UnknownContract);
                        let body = Message::Cancel(Cancel {
                            need: q.need,
                            reason: Reason::Timeout,
                            sender: Role::Provider,
                        });
                        send(out, id, Destination::Module(from), body);
                    }
                }
                return;
            }
            if self.clients.contains_key(&key) {
                // The client moved on without us hearing its cancel.
                self.remove_client(key, None, out);
                self.refresh_identity(now, out);
            }
            let Some(sel) = q.selected else { return };
            if let Ok(v) = self.can_serve(from, &q.service, q.priority, &q.lineage, false, now)
                && v > sel.value + self.cfg.hysteresis
            {
                let body = Message::BetterOffer(BetterOffer {
                    need: q.need,
                    value: v,
                    channel: self.channel_for(&q.service),
                });
                send(out, id, Destination::Module(from), body);
            }
            return;
        }
        if self.offer_for(&q.service).is_none() {
            self.drops.record(DropReason::NotProvided);
        }
        let existing = self.clients.contains_key(&key);
        let body = match self.can_serve(from, &q.service, q.priority, &q.lineage, existing, now) {
            Ok(value) => Message::Propose(Propose {
                query_id: q.query_id,
                need: q.need,
                value,
                channel: self.channel_for(&q.service),
            }),
            Err(reason) => Message::Refuse(Refuse {
                query_id: q.query_id,
                need: q.need,
                reason,
            }),
        };
        send(out, id, Destination::Module(from), body);
    }

    pub(super) fn slot_index(&self, need: u16) -> Option<usize> {
        self.needs.iter().position(|s| s.spec.rank == need)
    }

    pub(super) fn on_propose(&mut self, from: ModuleId, p: &Propose) {
        if let Some(round) = &mut self.probe
            && round.queries.get(&p.need) == Some(&p.query_id)
        {
            round.answered.insert(p.need);
            return;
        }
        let Some(i) = self.slot_index(p.need) else {
            self.drops.record(DropReason::StaleReply);
            return;
        };
        if let Some(proposals) = self.reply_to_call(i, from, p.query_id) {
            // Duplicates are resolved at the deadline (the last one counts).
            proposals.push(Proposal {
                provider: from,
                value: p.value,
                channel: p.channel.clone(),
            });
        }
    }

    /// The proposals of slot `i`'s open call `query_id`, `from` marked as having replied;
    /// `None`, counted as a stale reply, if that call is not open.
    fn reply_to_call(
        &mut self,
        i: usize,
        from: ModuleId,
        query_id: u64,
    ) -> Option<&mut Vec<Proposal>> {
        match &mut self.needs[i].state {
            NeedState::Calling {
                query_id: open,
                proposals,
                replied,
                ..
            } if *open == query_id => {
                replied.insert(from);
                Some(proposals)
            }
            _ => {
                self.drops.record(DropReason::StaleReply);
                None
            }
        }
    }

    pub(super) fn on_refuse(&mut self, from: ModuleId, r: &Refuse) {
        if self
            .probe
            .as_ref()
            .is_some_and(|round| round.queries.get(&r.need) == Some(&r.query_id))
        {
            return;
        }
        let Some(i) = self.slot_index(r.need) else {
            self.drops.record(DropReason::StaleReply);
            return;
        };
        if let Some(proposals) = self.reply_to_call(i, from, r.query_id) {
            proposals.retain(|x| x.provider != from);
        }
        self.needs[i].candidates.retain(|x| x.provider != from);
    }

    pub(super) fn on_accept(
        &mut self,
        from: ModuleId,
        a: &Accept,
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        let id = self.cfg.id;
        let key = (from, a.need);
        let existing = self.clients.contains_key(&key);
        match self.can_serve(
            from,
            &a.service,
            Some(a.priority),
            &a.lineage,
            existing,
            now,
        ) {
            Ok(value) => {
                let was_active = self.is_active();
                self.clients.insert(
                    key,
                    ClientContract {
                        service: a.service.clone(),
                        priority: a.priority,
                        lineage: a.lineage.clone(),
                        last_heard: now,
                    },
                );
                if !existing {
                    self.events.push(AgentEvent::ClientAdded {
                        client: from,
                        need: a.need,
                        priority: a.priority,
                    });
                }
                // Immediate value report: confirms the contract.
                let body = Message::Value(ValueReport {
                    need: a.need,
                    value,
                });
                send(out, id, Destination::Module(from), body);
                if !was_active {
                    self.next_probe = now;
                    self.probe = None;
                }
                self.refresh_identity(now, out);
            }
            Err(reason) => {
                if existing {
                    self.remove_client(key, Some(reason), out);
                    self.refresh_identity(now, out);
                } else {
                    let body = Message::Cancel(Cancel {
                        need: a.need,
                        reason,
                        sender: Role::Provider,
                    });
                    send(out, id, Destination::Module(from), body);
                }
            }
        }
    }

    pub(super) fn on_cancel(
        &mut self,
        from: ModuleId,
        c: &Cancel,
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        match c.sender {
            Role::Client => {
                let key = (from, c.need);
                if self.clients.contains_key(&key) {
                    self.remove_client(key, None, out);
                    self.refresh_identity(now, out);
                } else {
                    self.drops.record(DropReason::UnknownContract);
                }
            }
            Role::Provider => {
                let Some(i) = self.slot_index(c.need) else {
                    self.drops.record(DropReason::UnknownContract);
                    return;
                };
                self.needs[i].candidates.retain(|p| p.provider != from);
                match self.needs[i].state {
                    NeedState::Contracted { provider, .. } if provider == from => {
                        self.lose_provider(i, now, out);
                    }
                    _ => self.drops.record(DropReason::UnknownContract),
                }
            }
        }
    }

    pub(super) fn on_better_offer(
        &mut self,
        from: ModuleId,
        b: &BetterOffer,
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        let Some(i) = self.slot_index(b.need) else {
            self.drops.record(DropReason::StaleReply);
            return;
        };
        let hysteresis = self.cfg.hysteresis;
        let NeedState::Contracted {
            provider, value, ..
        } = self.needs[i].state
        else {
            self.drops.record(DropReason::StaleReply);
            return;
        };
        if provider == from || b.value <= value + hysteresis {
            self.drops.record(DropReason::StaleReply);
            return;
        }
        let dwell = self.cfg.timing.switch_back_dwell;
        if self.needs[i]
            .left
            .is_some_and(|(left, at)| left == from && now < at + dwell)
        {
            // Just left it: stay at least the dwell time (the offer comes again with the
            // next refresh).
            return;
        }
        let id = self.cfg.id;
        let body = Message::Cancel(Cancel {
            need: b.need,
            reason: Reason::Replaced,
            sender: Role::Client,
        });
        send(out, id, Destination::Module(provider), body);
        self.events.push(AgentEvent::ProviderLost {
            need: b.need,
            provider,
        });
        let slot = &mut self.needs[i];
        for c in &mut slot.candidates {
            if c.provider == provider {
                c.value = value;
            }
        }
        slot.candidates.retain(|c| c.provider != from);
        slot.candidates.push(Proposal {
            provider: from,
            value: b.value,
            channel: b.channel.clone(),
        });
        sort_best_first(&mut slot.candidates);
        let chosen = Proposal {
            provider: from,
            value: b.value,
            channel: b.channel.clone(),
        };
        self.contract_with(i, chosen, now, out);
    }

    pub(super) fn on_value(
        &mut self,
        from: ModuleId,
        v: &ValueReport,
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        let Some(i) = self.slot_index(v.need) else {
            self.drops.record(DropReason::UnknownContract);
            return;
        };
        if let NeedState::Contracted {
            provider,
            value,
            last_heard,
            ..
        } = &mut self.needs[i].state
            && *provider == from
        {
            *value = v.value;
            *last_heard = now;
            return;
        }
        // The provider believes in a contract we do not hold.
        self.drops.record(DropReason::UnknownContract);
        let body = Message::Cancel(Cancel {
            need: v.need,
            reason: Reason::NotNeeded,
            sender: Role::Client,
        });
        send(out, self.cfg.id, Destination::Module(from), body);
    }

    pub(super) fn on_update(
        &mut self,
        from: ModuleId,
        u: &ContractUpdate,
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        let key = (from, u.need);
        let Some(service) = self.clients.get(&key).map(|c| c.service.clone()) else {
            self.drops.record(DropReason::UnknownContract);
            return;
        };
        match self.can_serve(from, &service, Some(u.priority), &u.lineage, true, now) {
            Ok(_) => {
                if let Some(c) = self.clients.get_mut(&key) {
                    c.priority = u.priority;
                    c.lineage = u.lineage.clone();
                    c.last_heard = now;
                }
            }
            Err(reason) => self.remove_client(key, Some(reason), out),
        }
        self.refresh_identity(now, out);
    }

    /// Removes a client contract; with `Some(reason)` tells the client.
    pub(super) fn remove_client(
        &mut self,
        key: (ModuleId, u16),
        reason: Option<Reason>,
        out: &mut Vec<Outgoing>,
    ) {
        if self.clients.remove(&key).is_none() {
            return;
        }
        self.events.push(AgentEvent::ClientRemoved {
            client: key.0,
            need: key.1,
        });
        if let Some(reason) = reason {
            let body = Message::Cancel(Cancel {
                need: key.1,
                reason,
                sender: Role::Provider,
            });
            send(out, self.cfg.id, Destination::Module(key.0), body);
        }
    }
}
