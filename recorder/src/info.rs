//! `hng info FILE.mcap`: channels, schemas, counts, rates, duration and drops of a recording.

use std::collections::BTreeMap;
use std::path::Path;

use serde::Serialize;

use crate::Error;
use crate::read::{load, scan};

/// One channel of a recording.
#[derive(Debug, Clone, Serialize)]
pub struct ChannelStat {
    /// The channel (topic).
    pub channel: String,
    /// The hng type (`hng.type` metadata).
    pub hng_type: Option<String>,
    /// Schema name.
    pub schema: String,
    /// Schema encoding (`protobuf`, `jsonschema`).
    pub schema_encoding: String,
    /// Message encoding (`protobuf`, `json`).
    pub message_encoding: String,
    /// Messages.
    pub messages: u64,
    /// Average rate over the channel's own span of log time, Hz (0 with fewer than 2).
    pub rate_hz: f64,
    /// Messages lost before the recorder read them (`hng.drops` metadata).
    pub dropped: Option<u64>,
    first_log: u64,
    last_log: u64,
}

/// What `hng info` reports.
#[derive(Debug, Clone, Serialize)]
pub struct Info {
    /// The file.
    pub file: String,
    /// Its size.
    pub bytes: u64,
    /// Messages.
    pub messages: u64,
    /// From the first to the last message, log (wall) time, s.
    pub duration_s: f64,
    /// The channels, by name.
    pub channels: Vec<ChannelStat>,
    /// Messages lost in total (`hng.drops`), when the recorder wrote it.
    pub dropped: Option<u64>,
    /// False when the file is damaged (then `damage` says where).
    pub complete: bool,
    /// The damage, with its byte offset.
    pub damage: Option<String>,
    /// Metadata records.
    pub metadata: BTreeMap<String, BTreeMap<String, String>>,
    /// Attachments (the modules' checkpoints) by name: how many, and their bytes.
    pub attachments: BTreeMap<String, AttachmentStat>,
}

/// The attachments of one name.
#[derive(Debug, Clone, Default, Serialize)]
pub struct AttachmentStat {
    /// Media type (of the last one).
    pub media_type: String,
    /// How many.
    pub count: u64,
    /// Their bytes in all.
    pub bytes: u64,
}

/// Reads `path` and summarises it.
pub fn info(path: &Path) -> Result<Info, Error> {
    let buf = load(path)?;
    let mut per: BTreeMap<u16, (u64, u64, u64)> = BTreeMap::new();
    let contents = scan(path, &buf, &mut |ch, h, _| {
        let e = per.entry(ch.id).or_insert((0, u64::MAX, 0));
        e.0 += 1;
        e.1 = e.1.min(h.log_time);
        e.2 = e.2.max(h.log_time);
        Ok(())
    })?;
    let drops = contents.metadata("hng.drops");
    let mut channels: Vec<ChannelStat> = contents
        .channels
        .values()
        .map(|c| {
            let (n, first, last) = per.get(&c.id).copied().unwrap_or((0, 0, 0));
            let span = last.saturating_sub(first) as f64 * 1e-9;
            ChannelStat {
                channel: c.topic.clone(),
                hng_type: c.hng_type.clone(),
                schema: c.schema_name.clone(),
                schema_encoding: c.schema_encoding.clone(),
                message_encoding: c.message_encoding.clone(),
                messages: n,
                rate_hz: if n >= 2 && span > 0.0 {
                    (n - 1) as f64 / span
                } else {
                    0.0
                },
                dropped: drops
                    .and_then(|d| d.get(&c.topic))
                    .and_then(|v| v.parse().ok()),
                first_log: first,
                last_log: last,
            }
        })
        .collect();
    channels.sort_by(|a, b| a.channel.cmp(&b.channel));
    let with = channels.iter().filter(|c| c.messages > 0);
    let first = with.clone().map(|c| c.first_log).min().unwrap_or(0);
    let last = with.map(|c| c.last_log).max().unwrap_or(0);
    let mut attachments: BTreeMap<String, AttachmentStat> = BTreeMap::new();
    for a in &contents.attachments {
        let e = attachments.entry(a.name.clone()).or_default();
        e.media_type.clone_from(&a.media_type);
        e.count += 1;
        e.bytes += a.bytes;
    }
    Ok(Info {
        attachments,
        file: path.display().to_string(),
        bytes: contents.file_bytes,
        messages: channels.iter().map(|c| c.messages).sum(),
        duration_s: last.saturating_sub(first) as f64 * 1e-9,
        dropped: drops.map(|d| d.values().filter_map(|v| v.parse::<u64>().ok()).sum()),
        complete: contents.damage.is_none(),
        damage: contents.damage.as_ref().map(|e| e.to_string()),
        metadata: contents.metadata.iter().cloned().collect(),
        channels,
    })
}

impl std::fmt::Display for Info {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "file:      {} ({} bytes)", self.file, self.bytes)?;
        writeln!(f, "duration:  {:.3} s", self.duration_s)?;
        writeln!(
            f,
            "messages:  {} on {} channel(s), {} dropped",
            self.messages,
            self.channels.len(),
            self.dropped
                .map_or("unknown number".to_string(), |d| d.to_string())
        )?;
        if let Some(d) = &self.damage {
            writeln!(f, "DAMAGED:   {d}")?;
            writeln!(f, "           (the figures cover what precedes the damage)")?;
        }
        let w = self
            .channels
            .iter()
            .map(|c| c.channel.len())
            .max()
            .unwrap_or(7)
            .max(7);
        writeln!(
            f,
            "{:w$}  {:>8}  {:>9}  {:>7}  {:28}  encoding",
            "channel", "messages", "rate Hz", "dropped", "schema"
        )?;
        for c in &self.channels {
            writeln!(
                f,
                "{:w$}  {:>8}  {:>9.2}  {:>7}  {:28}  {}",
                c.channel,
                c.messages,
                c.rate_hz,
                c.dropped.map_or("-".to_string(), |d| d.to_string()),
                c.schema,
                c.message_encoding
            )?;
        }
        if !self.attachments.is_empty() {
            writeln!(f, "attachments:")?;
            for (name, a) in &self.attachments {
                writeln!(
                    f,
                    "  {name:w$}  {:>8}  {:>9} bytes  {}",
                    a.count, a.bytes, a.media_type
                )?;
            }
        }
        Ok(())
    }
}
