//! Contract heartbeats that say nothing new: a provider's value report and a client's refresh
//! query, sent every `refresh_period`, identical to the last one to the same destination for
//! the same need. They keep a contract alive (a peer's silence times out after
//! `peer_timeout`, 1 s by default) and change nothing a reader does before its next call, so
//! in lockstep they are sent unannounced ([`crate::channel::Node::unannounced`]): no round
//! opens for their readers, who read them with their next call (their own deadline, an input,
//! at the latest `lockstep_idle_s` later). A report or refresh whose content changed (a new
//! value, another selected provider, feedback, a new priority or lineage) wakes its readers
//! as before, so a re-negotiation is not delayed by it.

use crate::contract::{Destination, Message, Outgoing, QueryKind};

/// The last heartbeat sent to each destination for each need, without the fields that
/// change with every message (a query's id and reply deadline).
#[derive(Debug, Default)]
pub(super) struct Repeats {
    last: Vec<(Destination, u16, Message)>,
}

impl Repeats {
    /// True if `o` is a value report or a refresh query equal to the last one of its kind
    /// sent to the same destination for the same need, with nothing else sent there since.
    pub(super) fn repeated(&mut self, o: &Outgoing) -> bool {
        let (need, normal) = match &o.envelope.body {
            Message::Value(v) => (v.need, Message::Value(*v)),
            Message::Query(q) if q.kind == QueryKind::Refresh => {
                let mut q = q.clone();
                q.query_id = 0;
                q.reply_by_ns = 0;
                (q.need, Message::Query(q))
            }
            _ => {
                // Anything else to a destination is news, and so is the heartbeat after it
                // (a provider's first value report answers the client's accept).
                self.last.retain(|(to, _, _)| *to != o.to);
                return false;
            }
        };
        let same_kind = |m: &Message| {
            matches!(
                (m, &normal),
                (Message::Value(_), Message::Value(_)) | (Message::Query(_), Message::Query(_))
            )
        };
        match self
            .last
            .iter_mut()
            .find(|(to, n, m)| *to == o.to && *n == need && same_kind(m))
        {
            Some((_, _, last)) if *last == normal => true,
            Some((_, _, last)) => {
                *last = normal;
                false
            }
            None => {
                self.last.push((o.to.clone(), need, normal));
                false
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::contract::{Envelope, ModuleId, Query, Selected, ValueReport};

    fn out(to: Destination, body: Message) -> Outgoing {
        Outgoing {
            to,
            envelope: Envelope {
                from: ModuleId(1),
                body,
            },
        }
    }

    fn refresh(query_id: u64, value: f64) -> Message {
        Message::Query(Query {
            query_id,
            need: 2,
            service: "Localization".into(),
            kind: QueryKind::Refresh,
            priority: None,
            selected: Some(Selected {
                provider: ModuleId(7),
                value,
            }),
            feedback: None,
            reply_by_ns: query_id * 1_000,
            lineage: Vec::new(),
        })
    }

    #[test]
    fn only_a_heartbeat_equal_to_the_last_one_to_its_destination_is_a_repeat() {
        let mut r = Repeats::default();
        let to = Destination::Module(ModuleId(9));
        let value = |v: f64| Message::Value(ValueReport { need: 1, value: v });
        assert!(!r.repeated(&out(to.clone(), value(0.5))), "the first one");
        assert!(r.repeated(&out(to.clone(), value(0.5))));
        assert!(!r.repeated(&out(to.clone(), value(0.6))), "a new value");
        assert!(
            !r.repeated(&out(Destination::Module(ModuleId(8)), value(0.6))),
            "another client"
        );
        let svc = Destination::Providers("Localization".into());
        assert!(!r.repeated(&out(svc.clone(), refresh(1, 0.9))));
        assert!(
            r.repeated(&out(svc.clone(), refresh(2, 0.9))),
            "a new query id and reply deadline change nothing"
        );
        assert!(
            !r.repeated(&out(svc.clone(), refresh(3, 0.8))),
            "a new value"
        );
        let call = match refresh(4, 0.8) {
            Message::Query(mut q) => {
                q.kind = QueryKind::Call;
                Message::Query(q)
            }
            m => m,
        };
        assert!(
            !r.repeated(&out(svc.clone(), call.clone())),
            "a call is news"
        );
        assert!(!r.repeated(&out(svc.clone(), call)), "every time");
        assert!(
            !r.repeated(&out(svc, refresh(5, 0.8))),
            "the heartbeat after news is news"
        );
    }
}
