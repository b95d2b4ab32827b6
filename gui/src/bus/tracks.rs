//! The beacons the trackers track ("Track beacon" offers' channels): the latest track of each
//! beacon on each channel, shown with its tracker and the clients contracted to it.

use std::collections::BTreeMap;
use std::time::Instant;

use hng_runtime::Subscriber;
use hng_runtime::msg::{BeaconTrack, TRACK_PREDICTED, TRACK_SEEN};
use hng_runtime::system::ContractRole;
use serde_json::{Value, json};

use super::{State, TABLE_TTL};

/// A beacon's track is shown while it is at most this much older (by its stamp) than the
/// newest track on its channel, ns (trackers publish every image; while nothing is designated,
/// a beacon in view is reported in one image of five).
const TRACK_KEPT_NS: u64 = 1_000_000_000;

/// The service the trackers provide (its contracts say who uses which tracker).
const TRACK_SERVICE: &str = "Track beacon";

/// The trackers' channels and the latest track of each beacon on each.
pub(super) struct Tracks {
    channels: Vec<(String, Subscriber<BeaconTrack>)>,
    /// (channel index, beacon id) -> its latest track and when it came.
    latest: BTreeMap<(usize, u32), (BeaconTrack, Instant)>,
}

impl Tracks {
    pub(super) fn new(channels: Vec<(String, Subscriber<BeaconTrack>)>) -> Tracks {
        Tracks {
            channels,
            latest: BTreeMap::new(),
        }
    }

    /// Reads every channel; forgets tracks too old (by stamp on their channel, or a channel
    /// silent for [`TABLE_TTL`]). Whether anything changed.
    pub(super) fn poll(&mut self) -> bool {
        let now = Instant::now();
        let mut changed = false;
        for (i, (ch, sub)) in self.channels.iter().enumerate() {
            loop {
                match sub.receive() {
                    Ok(Some(t)) => {
                        self.latest.insert((i, t.beacon_id), (*t, now));
                        changed = true;
                    }
                    Ok(None) => break,
                    Err(e) => {
                        tracing::debug!("{ch}: {e}");
                        break;
                    }
                }
            }
        }
        let newest = self.newest();
        let before = self.latest.len();
        self.latest.retain(|(i, _), (t, at)| {
            let n = newest.get(i).copied().unwrap_or(0);
            t.header.stamp_ns.saturating_add(TRACK_KEPT_NS) >= n
                && now.saturating_duration_since(*at) < TABLE_TTL
        });
        changed || self.latest.len() != before
    }

    /// The newest stamp on each channel.
    fn newest(&self) -> BTreeMap<usize, u64> {
        let mut n = BTreeMap::new();
        for ((i, _), (t, _)) in &self.latest {
            let e = n.entry(*i).or_insert(0);
            *e = t.header.stamp_ns.max(*e);
        }
        n
    }
}

/// The tracks shown: each beacon on each tracker's channel, with the tracker (the provider
/// of the "Track beacon" contracts on that channel, else the channel's first part) and the
/// clients contracted to it.
pub(super) fn tracks(tr: &Tracks, st: &State) -> Value {
    let name = |id: u32| {
        st.tables
            .get(&id)
            .map(|(_, t)| t.module().to_owned())
            .unwrap_or_else(|| format!("m{id}"))
    };
    let newest = tr.newest();
    let list: Vec<Value> = tr
        .latest
        .iter()
        .map(|((i, _), (t, _))| {
            let ch = &tr.channels[*i].0;
            let mut clients = Vec::new();
            let mut provider = None;
            for (_, table) in st.tables.values() {
                for e in table.entries().iter().filter(|e| {
                    e.role() == Some(ContractRole::Client)
                        && e.service() == TRACK_SERVICE
                        && e.channel() == ch.as_str()
                }) {
                    clients.push(table.module().to_owned());
                    provider = Some(name(e.peer));
                }
            }
            let tracker = provider.unwrap_or_else(|| ch.split('/').next().unwrap_or(ch).to_owned());
            let age = newest
                .get(i)
                .copied()
                .unwrap_or(0)
                .saturating_sub(t.header.stamp_ns);
            json!({
                "channel": ch,
                "tracker": tracker,
                "contracted_by": clients,
                "beacon_id": t.beacon_id,
                "state": match t.state {
                    TRACK_SEEN => "seen",
                    TRACK_PREDICTED => "predicted",
                    _ => "lost",
                },
                "bearing": t.bearing,
                "range": t.range,
                "quality": t.quality,
                "age_s": age as f64 / 1e9,
            })
        })
        .collect();
    json!({ "tracks": list })
}
