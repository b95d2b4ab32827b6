//! The agent's state machine, time side: its identity, calls for providers, contracts,
//! refreshes, timeouts and probes.

use std::collections::BTreeSet;
use std::time::Duration;

use super::*;

impl ContractAgent {
    /// Recomputes the priority and lineage from the client contracts and
    /// propagates changes to the providers; deactivates when no contract is left.
    pub(super) fn refresh_identity(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        let id = self.cfg.id;
        let (priority, lineage) = if self.cfg.manager {
            (Some(Priority::ROOT), vec![id])
        } else {
            let p = Priority::most_important(self.clients.values().map(|c| c.priority));
            let mut set: BTreeSet<ModuleId> = BTreeSet::new();
            set.insert(id);
            for c in self.clients.values() {
                set.extend(c.lineage.iter().copied());
            }
            (p, set.into_iter().collect())
        };
        let was = self.priority;
        let lineage_changed = lineage != self.lineage;
        self.priority = priority;
        self.lineage = lineage;
        match (was, priority) {
            (None, Some(p)) => self.events.push(AgentEvent::Activated { priority: p }),
            (Some(_), None) => {
                self.events.push(AgentEvent::Deactivated);
                self.deactivate_needs(out);
                return;
            }
            (Some(a), Some(b)) if a != b => self
                .events
                .push(AgentEvent::PriorityChanged { priority: b }),
            _ => {}
        }
        if (was != priority || lineage_changed)
            && let Some(p) = priority
        {
            for i in 0..self.needs.len() {
                let rank = self.needs[i].spec.rank;
                if let NeedState::Contracted { provider, .. } = self.needs[i].state {
                    match p.child(rank) {
                        Ok(np) => {
                            let body = Message::Update(ContractUpdate {
                                need: rank,
                                priority: np,
                                lineage: self.lineage.clone(),
                            });
                            send(out, id, Destination::Module(provider), body);
                        }
                        Err(_) => self.lose_provider(i, now, out),
                    }
                }
            }
        }
    }

    /// The module became inactive: cancel its own provider contracts.
    pub(super) fn deactivate_needs(&mut self, out: &mut Vec<Outgoing>) {
        let id = self.cfg.id;
        for slot in &mut self.needs {
            if let NeedState::Contracted { provider, .. } = slot.state {
                let body = Message::Cancel(Cancel {
                    need: slot.spec.rank,
                    reason: Reason::NotNeeded,
                    sender: Role::Client,
                });
                send(out, id, Destination::Module(provider), body);
                self.events.push(AgentEvent::ProviderLost {
                    need: slot.spec.rank,
                    provider,
                });
            }
            slot.state = NeedState::Idle;
            slot.candidates.clear();
        }
    }

    /// Need `i` is switched off: end its contract or call.
    pub(super) fn switch_off(&mut self, i: usize, out: &mut Vec<Outgoing>) {
        let slot = &mut self.needs[i];
        match std::mem::replace(&mut slot.state, NeedState::Idle) {
            NeedState::Contracted { provider, .. } => {
                let body = Message::Cancel(Cancel {
                    need: slot.spec.rank,
                    reason: Reason::NotNeeded,
                    sender: Role::Client,
                });
                self.events.push(AgentEvent::ProviderLost {
                    need: slot.spec.rank,
                    provider,
                });
                send(out, self.cfg.id, Destination::Module(provider), body);
            }
            NeedState::Calling { .. } | NeedState::Waiting { .. } | NeedState::Idle => {}
        }
        self.needs[i].candidates.clear();
        self.needs[i].optional_unmet = false;
    }

    /// Need `i` lost its provider (dead, cancelled, silent): next best at once.
    pub(super) fn lose_provider(&mut self, i: usize, now: Duration, out: &mut Vec<Outgoing>) {
        if let NeedState::Contracted { provider, .. } = self.needs[i].state {
            self.needs[i].candidates.retain(|c| c.provider != provider);
            self.events.push(AgentEvent::ProviderLost {
                need: self.needs[i].spec.rank,
                provider,
            });
        }
        self.needs[i].state = NeedState::Idle;
        if self.priority.is_none() || !self.needs[i].enabled {
            return;
        }
        match self.needs[i].candidates.first().cloned() {
            Some(next) => self.contract_with(i, next, now, out),
            None => self.start_call(i, now, out),
        }
    }

    pub(super) fn contract_with(
        &mut self,
        i: usize,
        p: Proposal,
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        let rank = self.needs[i].spec.rank;
        let priority = match self.need_priority(rank) {
            Some(p) if self.needs[i].enabled => p,
            _ => {
                self.needs[i].state = NeedState::Idle;
                return;
            }
        };
        let id = self.cfg.id;
        let body = Message::Accept(Accept {
            need: rank,
            service: self.needs[i].spec.service.clone(),
            priority,
            lineage: self.lineage.clone(),
        });
        send(out, id, Destination::Module(p.provider), body);
        self.events.push(AgentEvent::ProviderSelected {
            need: rank,
            provider: p.provider,
            channel: p.channel.clone(),
        });
        let slot = &mut self.needs[i];
        slot.optional_unmet = false;
        // An evaluation belongs to the contract it was made in: a provider that comes back
        // starts clean (the stale one, re-sent at every refresh, took the contract from it
        // again right after the dwell time).
        slot.evaluation = None;
        if let Some(prev) = slot.last_provider
            && prev != p.provider
        {
            slot.left = Some((prev, now));
        }
        slot.last_provider = Some(p.provider);
        slot.state = NeedState::Contracted {
            provider: p.provider,
            channel: p.channel,
            value: p.value,
            last_heard: now,
            next_refresh: now + self.cfg.timing.refresh_period,
        };
    }

    pub(super) fn fresh_query_id(&mut self) -> u64 {
        let q = self.next_query_id;
        self.next_query_id = self.next_query_id.wrapping_add(1);
        q
    }

    pub(super) fn start_call(&mut self, i: usize, now: Duration, out: &mut Vec<Outgoing>) {
        let rank = self.needs[i].spec.rank;
        let Some(priority) = self.need_priority(rank) else {
            // Too deep (or inactive): the need cannot be contracted.
            self.need_unmet(i, now, out);
            return;
        };
        let query_id = self.fresh_query_id();
        let deadline = now + self.cfg.timing.reply_window;
        let body = Message::Query(Query {
            query_id,
            need: rank,
            service: self.needs[i].spec.service.clone(),
            kind: QueryKind::Call,
            priority: Some(priority),
            selected: None,
            feedback: None,
            reply_by_ns: duration_ns(deadline),
            lineage: self.lineage.clone(),
        });
        let to = Destination::Providers(self.needs[i].spec.service.clone());
        send(out, self.cfg.id, to, body);
        self.needs[i].state = NeedState::Calling {
            query_id,
            deadline,
            proposals: Vec::new(),
            replied: BTreeSet::new(),
        };
    }

    pub(super) fn close_call(&mut self, i: usize, now: Duration, out: &mut Vec<Outgoing>) {
        let NeedState::Calling {
            query_id,
            proposals,
            ..
        } = std::mem::replace(&mut self.needs[i].state, NeedState::Idle)
        else {
            return;
        };
        // Keep the last proposal of each provider.
        let mut seen = BTreeSet::new();
        let mut proposals: Vec<Proposal> = proposals
            .into_iter()
            .rev()
            .filter(|p| p.value.is_finite() && seen.insert(p.provider))
            .collect();
        sort_best_first(&mut proposals);
        let Some(best) = proposals.first().cloned() else {
            self.needs[i].candidates.clear();
            self.need_unmet(i, now, out);
            return;
        };
        let rank = self.needs[i].spec.rank;
        for other in proposals.iter().skip(1) {
            let body = Message::Reject(Reject {
                query_id,
                need: rank,
            });
            send(out, self.cfg.id, Destination::Module(other.provider), body);
        }
        self.needs[i].candidates = proposals;
        self.contract_with(i, best, now, out);
    }

    pub(super) fn need_unmet(&mut self, i: usize, now: Duration, out: &mut Vec<Outgoing>) {
        let retry_at = now + self.cfg.timing.retry_period;
        if !self.needs[i].spec.is_required() {
            self.needs[i].optional_unmet = true;
            self.needs[i].state = NeedState::Waiting { retry_at };
            return;
        }
        if self.cfg.manager {
            self.needs[i].state = NeedState::Waiting { retry_at };
            return;
        }
        // A required need cannot be met: the module cannot work. Cancel upward.
        self.needs[i].state = NeedState::Idle;
        self.known_unmet = true;
        self.next_probe = now + self.cfg.timing.probe_period;
        self.probe = None;
        let keys: Vec<(ModuleId, u16)> = self.clients.keys().copied().collect();
        for key in keys {
            self.remove_client(key, Some(Reason::NeedsUnmet), out);
        }
        self.refresh_identity(now, out);
    }

    pub(super) fn outgoing_feedback(
        &mut self,
        i: usize,
        provider: ModuleId,
        now: Duration,
    ) -> Option<f32> {
        match &mut self.needs[i].evaluation {
            // The module's own judgement of this provider: once.
            Some((p, e, sent)) if *p == provider => {
                let first = !std::mem::replace(sent, true);
                first.then_some(*e as f32)
            }
            _ => self.feedback.mean(now).map(|m| m as f32),
        }
    }

    pub(super) fn step(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        let id = self.cfg.id;
        let t = self.cfg.timing;
        self.feedback.prune(now);

        // Provider side: silent clients, degraded mode (serve nothing included), lost
        // aptitude.
        let unavailable = self.value(now).is_err();
        let min = self.min_priority;
        let serve_nothing = self.lacking_resources;
        let drop: Vec<((ModuleId, u16), Option<Reason>)> = self
            .clients
            .iter()
            .filter_map(|(k, c)| {
                if now.saturating_sub(c.last_heard) > t.peer_timeout {
                    Some((*k, Some(Reason::Timeout)))
                } else if unavailable {
                    Some((*k, Some(Reason::Inactive)))
                } else if serve_nothing {
                    Some((*k, Some(Reason::NoResources)))
                } else if min.is_some_and(|m| !c.priority.admitted_by(&m)) {
                    Some((*k, Some(Reason::Degraded)))
                } else {
                    None
                }
            })
            .collect();
        if !drop.is_empty() {
            for (k, r) in drop {
                self.remove_client(k, r, out);
            }
            self.refresh_identity(now, out);
        }

        // Provider side: periodic value reports (heartbeats).
        if now >= self.next_report {
            self.next_report = now + t.refresh_period;
            if let Ok(value) = self.value(now) {
                for &(client, need) in self.clients.keys() {
                    let body = Message::Value(ValueReport { need, value });
                    send(out, id, Destination::Module(client), body);
                }
            }
        }

        // Client side.
        if self.priority.is_some() {
            for i in 0..self.needs.len() {
                if !self.needs[i].enabled {
                    self.switch_off(i, out);
                    continue;
                }
                match &self.needs[i].state {
                    NeedState::Idle => self.start_call(i, now, out),
                    NeedState::Calling {
                        deadline, replied, ..
                    } if now >= *deadline || self.all_replied(i, replied.len()) => {
                        self.close_call(i, now, out)
                    }
                    NeedState::Waiting { retry_at } if now >= *retry_at => {
                        self.start_call(i, now, out)
                    }
                    &NeedState::Contracted {
                        provider,
                        value,
                        last_heard,
                        next_refresh,
                        ..
                    } => {
                        if now.saturating_sub(last_heard) > t.peer_timeout {
                            self.lose_provider(i, now, out);
                        } else if now >= next_refresh {
                            self.send_refresh(i, provider, value, now, out);
                        }
                    }
                    _ => {}
                }
                if self.priority.is_none() {
                    // A required need failed and the module deactivated.
                    break;
                }
            }
        }

        // Inactive module whose required need failed: probe.
        if self.known_unmet && !self.is_active() {
            self.step_probe(now, out);
        }
    }

    /// The earliest time at which [`ContractAgent::tick`] has something to do: a call to
    /// close or to start, a retry, a refresh or heartbeat to send, a silent peer to time out,
    /// a probe round to start or end. `None`: nothing is scheduled. A transport wakes the
    /// agent then (or on input, or after changing its inputs with a setter), instead of
    /// ticking it on a fixed period; ticking more often changes nothing.
    ///
    /// Time-weighted feedback fades continuously; a value that crosses 0 by fading alone is
    /// noticed at the next scheduled time (at most a refresh period while clients exist).
    pub fn next_deadline(&self) -> Option<Duration> {
        let t = self.cfg.timing;
        let timeout = |last: Duration| last + t.peer_timeout + Duration::from_nanos(1);
        let mut at: Option<Duration> = None;
        let mut due = |d: Duration| at = Some(at.map_or(d, |a| a.min(d)));
        if !self.clients.is_empty() {
            due(self.next_report);
            for c in self.clients.values() {
                due(timeout(c.last_heard));
            }
        }
        if self.priority.is_some() {
            for (i, slot) in self.needs.iter().enumerate() {
                match &slot.state {
                    NeedState::Idle if slot.enabled => due(Duration::ZERO),
                    NeedState::Idle => {}
                    _ if !slot.enabled => due(Duration::ZERO),
                    NeedState::Calling {
                        deadline, replied, ..
                    } => {
                        if self.all_replied(i, replied.len()) {
                            due(Duration::ZERO);
                        } else {
                            due(*deadline);
                        }
                    }
                    NeedState::Waiting { retry_at } => due(*retry_at),
                    NeedState::Contracted {
                        last_heard,
                        next_refresh,
                        ..
                    } => {
                        due(timeout(*last_heard));
                        due(*next_refresh);
                    }
                }
            }
        }
        if self.known_unmet && !self.is_active() {
            match &self.probe {
                Some(round) => due(round.deadline),
                None => due(self.next_probe),
            }
        }
        at
    }

    /// True while a need waits for a provider to appear (a retry is scheduled) or a probe
    /// looks for the providers of a failed required need: a transport that learns of new
    /// providers ([`ContractAgent::set_provider_count`]) should tell the agent then.
    pub fn waiting_for_providers(&self) -> bool {
        (self.known_unmet && !self.is_active())
            || self
                .needs
                .iter()
                .any(|n| n.enabled && matches!(n.state, NeedState::Waiting { .. }))
    }

    pub(super) fn send_refresh(
        &mut self,
        i: usize,
        provider: ModuleId,
        value: f64,
        now: Duration,
        out: &mut Vec<Outgoing>,
    ) {
        let rank = self.needs[i].spec.rank;
        let feedback = self.outgoing_feedback(i, provider, now);
        let query_id = self.fresh_query_id();
        let t = self.cfg.timing;
        let body = Message::Query(Query {
            query_id,
            need: rank,
            service: self.needs[i].spec.service.clone(),
            kind: QueryKind::Refresh,
            priority: self.need_priority(rank),
            selected: Some(Selected { provider, value }),
            feedback,
            reply_by_ns: duration_ns(now + t.reply_window),
            lineage: self.lineage.clone(),
        });
        let to = Destination::Providers(self.needs[i].spec.service.clone());
        send(out, self.cfg.id, to, body);
        if let NeedState::Contracted { next_refresh, .. } = &mut self.needs[i].state {
            *next_refresh = now + t.refresh_period;
        }
    }

    pub(super) fn step_probe(&mut self, now: Duration, out: &mut Vec<Outgoing>) {
        let t = self.cfg.timing;
        if let Some(round) = &self.probe {
            if now < round.deadline {
                return;
            }
            let all = round.queries.keys().all(|n| round.answered.contains(n));
            self.probe = None;
            if all {
                self.known_unmet = false;
            } else {
                self.next_probe = now + t.probe_period;
            }
            return;
        }
        if now < self.next_probe {
            return;
        }
        let mut queries = BTreeMap::new();
        for i in 0..self.needs.len() {
            if !self.needs[i].spec.is_required() {
                continue;
            }
            let query_id = self.fresh_query_id();
            let rank = self.needs[i].spec.rank;
            queries.insert(rank, query_id);
            let body = Message::Query(Query {
                query_id,
                need: rank,
                service: self.needs[i].spec.service.clone(),
                kind: QueryKind::Probe,
                priority: None,
                selected: None,
                feedback: None,
                reply_by_ns: duration_ns(now + t.reply_window),
                lineage: self.lineage.clone(),
            });
            let to = Destination::Providers(self.needs[i].spec.service.clone());
            send(out, self.cfg.id, to, body);
        }
        self.probe = Some(ProbeRound {
            deadline: now + t.reply_window,
            queries,
            answered: BTreeSet::new(),
        });
    }
}
