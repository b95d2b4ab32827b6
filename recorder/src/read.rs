//! Reading a recording from start to end, record by record, so that a damaged file (cut
//! short by a crash or a full disk, or corrupted) yields every message before the damage and
//! an error naming the byte offset of the first bad record.
//!
//! The framing of the top-level records (opcode, length) is walked here to know the offsets;
//! each record is parsed, and each chunk decompressed and read, by the `mcap` crate.

use std::collections::BTreeMap;
use std::path::Path;

use mcap::records::{MessageHeader, Record};

use crate::Error;

/// A channel of a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelInfo {
    /// MCAP channel id.
    pub id: u16,
    /// The topic (hng channel name).
    pub topic: String,
    /// `protobuf` or `json`.
    pub message_encoding: String,
    /// Schema name (`foxglove.LaserScan`, `hng/Twist/v1`, ...).
    pub schema_name: String,
    /// Schema encoding.
    pub schema_encoding: String,
    /// The hng type (channel metadata `hng.type`), if written by hng.
    pub hng_type: Option<String>,
}

/// An attachment of a recording (a module's checkpoint).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct AttachmentInfo {
    /// Its name (`checkpoint/slam`).
    pub name: String,
    /// Its media type.
    pub media_type: String,
    /// When the recorder stored it, ns since the Unix epoch.
    pub log_time: u64,
    /// When it was created (the checkpoint file's modification time), ns.
    pub create_time: u64,
    /// Its size.
    pub bytes: u64,
}

/// What a pass over a file found besides its messages.
#[derive(Debug, Default)]
pub struct Contents {
    /// Channels by id.
    pub channels: BTreeMap<u16, ChannelInfo>,
    /// Metadata records, in file order.
    pub metadata: Vec<(String, BTreeMap<String, String>)>,
    /// Attachments (the modules' checkpoints), in file order, without their data.
    pub attachments: Vec<AttachmentInfo>,
    /// The damage that stopped the pass, if any (everything before it was read).
    pub damage: Option<Error>,
    /// Bytes in the file.
    pub file_bytes: u64,
}

impl Contents {
    /// The metadata record `name` (the last one of that name).
    pub fn metadata(&self, name: &str) -> Option<&BTreeMap<String, String>> {
        self.metadata
            .iter()
            .rev()
            .find(|(n, _)| n == name)
            .map(|(_, m)| m)
    }
}

/// Reads the whole file.
pub fn load(path: &Path) -> Result<Vec<u8>, Error> {
    std::fs::read(path).map_err(|e| Error::Io {
        path: path.display().to_string(),
        source: e,
    })
}

type OnMessage<'f> = dyn FnMut(&ChannelInfo, &MessageHeader, &[u8]) -> Result<(), Error> + 'f;

/// Walks `buf` (the bytes of `path`), calling `on_message` for every message in file order.
/// An error of `on_message` ends the pass and is returned; damage ends it too and is kept in
/// [`Contents::damage`].
pub fn scan(path: &Path, buf: &[u8], on_message: &mut OnMessage<'_>) -> Result<Contents, Error> {
    let mut st = State {
        path,
        contents: Contents {
            file_bytes: buf.len() as u64,
            ..Contents::default()
        },
        schemas: BTreeMap::new(),
    };
    let damaged = |offset: usize, detail: String| Error::Damaged {
        path: path.display().to_string(),
        offset: offset as u64,
        detail,
    };
    if buf.len() < mcap::MAGIC.len() || &buf[..mcap::MAGIC.len()] != mcap::MAGIC {
        st.contents.damage = Some(damaged(0, "not an MCAP file (no MCAP magic)".into()));
        return Ok(st.contents);
    }
    let mut o = mcap::MAGIC.len();
    // The records of the last chunk, uncompressed: its message indexes point into them.
    let mut last_chunk: Vec<u8> = Vec::new();
    loop {
        if o == buf.len() {
            st.contents.damage = Some(damaged(
                o,
                "the file ends here without its footer (cut short: a crash or a full disk?)".into(),
            ));
            break;
        }
        if buf.len() - o < 9 {
            st.contents.damage = Some(damaged(
                o,
                format!(
                    "a record header needs 9 bytes, {} left: the file is cut short",
                    buf.len() - o
                ),
            ));
            break;
        }
        let op = buf[o];
        let mut len8 = [0u8; 8];
        len8.copy_from_slice(&buf[o + 1..o + 9]);
        let len = u64::from_le_bytes(len8);
        let end = (o as u64 + 9).checked_add(len);
        let Some(end) = end.filter(|e| *e <= buf.len() as u64) else {
            st.contents.damage = Some(damaged(
                o,
                format!(
                    "record (opcode 0x{op:02x}) of {len} bytes runs past the end of the file ({} bytes): cut short or corrupted",
                    buf.len()
                ),
            ));
            break;
        };
        let end = end as usize;
        let body = &buf[o + 9..end];
        let record = match mcap::read::parse_record(op, body) {
            Ok(r) => r,
            Err(e) => {
                st.contents.damage = Some(damaged(o, format!("record (opcode 0x{op:02x}): {e}")));
                break;
            }
        };
        match record {
            Record::Chunk { header, data } => {
                match chunk_records(&header, &data) {
                    Ok(raw) => last_chunk = raw,
                    Err(detail) => {
                        st.contents.damage = Some(damaged(o, detail));
                        break;
                    }
                }
                let reader = match mcap::read::ChunkReader::new(header, &data) {
                    Ok(r) => r,
                    Err(e) => {
                        st.contents.damage = Some(damaged(o, format!("chunk: {e}")));
                        break;
                    }
                };
                let mut bad = None;
                for r in reader {
                    match r {
                        Ok(rec) => st.record(rec, on_message)?,
                        Err(e) => {
                            bad = Some(damaged(o, format!("chunk: {e}")));
                            break;
                        }
                    }
                }
                if bad.is_some() {
                    st.contents.damage = bad;
                    break;
                }
            }
            Record::MessageIndex(index) => {
                // MCAP gives a message index no CRC: bytes overwritten in one are caught by
                // checking each entry against the message it points to.
                if let Err(detail) = check_message_index(&index, &last_chunk) {
                    st.contents.damage = Some(damaged(o, detail));
                    break;
                }
            }
            Record::DataEnd(_) | Record::Footer(_) => break,
            rec => st.record(rec, on_message)?,
        }
        o = end;
    }
    Ok(st.contents)
}

/// A chunk's records, uncompressed, checked against the chunk's CRC (when the writer set
/// one): corruption that still decompresses is caught here. Empty for a compression this
/// reader does not decompress itself (the `mcap` crate's reader checks what it can).
fn chunk_records(header: &mcap::records::ChunkHeader, data: &[u8]) -> Result<Vec<u8>, String> {
    let raw = match header.compression.as_str() {
        "" => data.to_vec(),
        "zstd" => zstd::bulk::decompress(data, header.uncompressed_size as usize)
            .map_err(|e| format!("chunk: zstd: {e}"))?,
        _ => return Ok(Vec::new()),
    };
    if header.uncompressed_crc == 0 {
        return Ok(raw);
    }
    let crc = crc32fast::hash(&raw);
    if crc != header.uncompressed_crc {
        return Err(format!(
            "chunk CRC {crc:08x} differs from the recorded {:08x}: corrupted",
            header.uncompressed_crc
        ));
    }
    Ok(raw)
}

/// Checks every entry of a message index against the chunk before it: the entry must point
/// at a message record of the index's channel with the entry's log time.
fn check_message_index(index: &mcap::records::MessageIndex, chunk: &[u8]) -> Result<(), String> {
    if chunk.is_empty() {
        return Ok(()); // a compression not decompressed here: nothing to check against
    }
    for (i, e) in index.records.iter().enumerate() {
        let bad = |what: &str| {
            Err(format!(
                "message index of channel {}: entry {i} (offset {} in the chunk, log time {}) {what}: corrupted",
                index.channel_id, e.offset, e.log_time
            ))
        };
        // Message record: opcode, length (8), channel id (2), sequence (4), log time (8), ...
        let Some(at) = usize::try_from(e.offset)
            .ok()
            .filter(|o| o + 23 <= chunk.len())
        else {
            return bad("points past the end of the chunk");
        };
        if chunk[at] != 0x05 {
            return bad("does not point at a message record");
        }
        let channel = u16::from_le_bytes([chunk[at + 9], chunk[at + 10]]);
        let mut t = [0u8; 8];
        t.copy_from_slice(&chunk[at + 15..at + 23]);
        if channel != index.channel_id || u64::from_le_bytes(t) != e.log_time {
            return bad("does not match the message it points at");
        }
    }
    Ok(())
}

struct State<'p> {
    path: &'p Path,
    contents: Contents,
    schemas: BTreeMap<u16, (String, String)>,
}

impl State<'_> {
    fn record(&mut self, rec: Record<'_>, on_message: &mut OnMessage<'_>) -> Result<(), Error> {
        match rec {
            Record::Schema { header, .. } => {
                self.schemas
                    .insert(header.id, (header.name, header.encoding));
            }
            Record::Channel(c) => {
                let (schema_name, schema_encoding) =
                    self.schemas.get(&c.schema_id).cloned().unwrap_or_default();
                self.contents.channels.insert(
                    c.id,
                    ChannelInfo {
                        id: c.id,
                        hng_type: c.metadata.get("hng.type").cloned(),
                        topic: c.topic,
                        message_encoding: c.message_encoding,
                        schema_name,
                        schema_encoding,
                    },
                );
            }
            Record::Message { header, data } => {
                match self.contents.channels.get(&header.channel_id) {
                    Some(ch) => on_message(ch, &header, &data)?,
                    None => {
                        return Err(Error::Mcap {
                            path: self.path.display().to_string(),
                            detail: format!(
                                "a message on channel id {} before that channel's record",
                                header.channel_id
                            ),
                        });
                    }
                }
            }
            Record::Metadata(m) => self.contents.metadata.push((m.name, m.metadata)),
            Record::Attachment { header, data, .. } => {
                self.contents.attachments.push(AttachmentInfo {
                    name: header.name,
                    media_type: header.media_type,
                    log_time: header.log_time,
                    create_time: header.create_time,
                    bytes: data.len() as u64,
                });
            }
            _ => {}
        }
        Ok(())
    }
}
