//! How each hng message type is written to MCAP and read back.
//!
//! Where a Foxglove well-known schema fits, a message is written in it (protobuf), so
//! Foxglove and Lichtblick show it without configuration:
//!
//! | hng type | Foxglove schema |
//! |---|---|
//! | `LaserScan` | `foxglove.LaserScan` |
//! | `PoseWithCovariance` | `foxglove.PoseInFrame` |
//! | `Odometry` | `foxglove.FrameTransforms` (parent: the header's frame, child: `child_frame_id`) |
//! | `GridInfo` + cells | `foxglove.Grid` (one `int8` field, `occupancy`) |
//! | `ImageInfo` + bytes | `foxglove.RawImage` |
//! | `PathInfo` + poses | `foxglove.PosesInFrame` (a planned path) |
//!
//! Every other type is written as JSON (its serde form) with a JSON Schema inferred from the
//! type's default value.
//!
//! Every message also carries hng's own bytes of the message, so a replay republishes exactly
//! what was recorded (the well-known schemas have no room for, e.g., a scan's `range_max`):
//! in protobuf messages as field 15000 (`bytes`), which readers that only know the Foxglove
//! schema skip as an unknown field; in JSON as `hng_raw` (base64). The bytes are the
//! `#[repr(C)]` layout of the type named in the channel's `hng.type` metadata (little-endian,
//! this build's layout: the type name carries a version that changes with the layout).
//! Slice payloads travel in the well-known message's data field (grids, images) or as
//! `hng_data` (base64) in JSON.

use std::mem::size_of;

use base64::Engine as _;
use base64::engine::general_purpose::STANDARD as B64;
use foxglove::messages as fg;
use hng_runtime::contract::wire;
use hng_runtime::control::ControlInfo;
use hng_runtime::msg::{
    GridInfo, Header, ImageInfo, LaserScan, MAX_BEAMS, Message, Odometry, PathInfo, Pose2D,
    PoseWithCovariance, SliceMessage,
};
use prost::Message as _;
use serde_json::{Map, Value};

/// Protobuf field number of hng's own bytes in well-known messages.
pub const RAW_FIELD: u32 = 15000;

/// The schema and encoding of a channel.
#[derive(Debug, Clone, PartialEq)]
pub struct SchemaDesc {
    /// Schema name (`foxglove.LaserScan`, or hng's type name).
    pub name: String,
    /// Schema encoding: `protobuf` or `jsonschema`.
    pub encoding: &'static str,
    /// The schema itself (a FileDescriptorSet or a JSON Schema).
    pub data: Vec<u8>,
    /// Message encoding: `protobuf` or `json`.
    pub message_encoding: &'static str,
}

/// A fixed-size message type the recorder knows.
pub trait FixedCodec: Message {
    /// The channel's schema.
    fn schema() -> SchemaDesc;
    /// Appends the encoded message to `out`.
    fn encode(&self, out: &mut Vec<u8>) -> Result<(), String>;
    /// The message back from its encoding.
    fn decode(data: &[u8]) -> Result<Self, String>;
}

/// A variable-size message type the recorder knows.
pub trait SliceCodec: SliceMessage {
    /// The channel's schema.
    fn schema() -> SchemaDesc;
    /// Appends the encoded header and payload to `out`.
    fn encode(&self, data: &[Self::Elem], out: &mut Vec<u8>) -> Result<(), String>;
    /// The header and payload back from their encoding.
    fn decode(data: &[u8]) -> Result<(Self, Vec<Self::Elem>), String>;
}

/// The bytes of a plain `#[repr(C)]` value.
pub(crate) fn raw_of<T: Copy>(v: &T) -> &[u8] {
    // SAFETY: hng messages are `#[repr(C)]` plain data (ZeroCopySend: no pointers); the
    // slice covers exactly the value and lives as long as the borrow.
    unsafe { std::slice::from_raw_parts((v as *const T).cast::<u8>(), size_of::<T>()) }
}

/// A value of a plain `#[repr(C)]` type from its bytes.
pub(crate) fn from_raw<T: Copy + Default>(b: &[u8]) -> Result<T, String> {
    if b.len() != size_of::<T>() {
        return Err(format!(
            "hng bytes of {} bytes, the type has {} (another layout version?)",
            b.len(),
            size_of::<T>()
        ));
    }
    let mut v = T::default();
    // SAFETY: hng message types are plain data whose every bit pattern is valid (integers,
    // floats, byte arrays; enumerations travel as u8), and `b` has exactly size_of::<T>() bytes.
    unsafe {
        std::ptr::copy_nonoverlapping(b.as_ptr(), (&mut v as *mut T).cast::<u8>(), size_of::<T>());
    }
    Ok(v)
}

/// The header of a message's hng bytes (every hng message starts with its [`Header`]).
pub fn header_of_raw(raw: &[u8]) -> Option<Header> {
    raw.get(..size_of::<Header>())
        .and_then(|b| from_raw::<Header>(b).ok())
}

/// hng's bytes inside a protobuf message (field [`RAW_FIELD`]); other fields are skipped.
#[derive(Clone, PartialEq, prost::Message)]
struct Trailer {
    #[prost(bytes = "vec", tag = "15000")]
    raw: Vec<u8>,
}

fn append_trailer(raw: &[u8], out: &mut Vec<u8>) -> Result<(), String> {
    Trailer { raw: raw.to_vec() }
        .encode(out)
        .map_err(|e| e.to_string())
}

fn trailer(data: &[u8]) -> Result<Vec<u8>, String> {
    let t = Trailer::decode(data).map_err(|e| format!("protobuf: {e}"))?;
    if t.raw.is_empty() {
        return Err("no hng bytes (field 15000) in the message: not written by hng".into());
    }
    Ok(t.raw)
}

/// The schema of a Foxglove well-known type (protobuf), as the file stores it.
pub(crate) fn wkt_schema<M: foxglove::Encode>() -> SchemaDesc {
    match M::get_schema() {
        Some(s) => SchemaDesc {
            name: s.name,
            encoding: "protobuf",
            data: s.data.into_owned(),
            message_encoding: "protobuf",
        },
        None => SchemaDesc {
            name: String::new(),
            encoding: "protobuf",
            data: Vec::new(),
            message_encoding: "protobuf",
        },
    }
}

fn timestamp(h: &Header) -> Option<fg::Timestamp> {
    let s = h.stamp_ns / 1_000_000_000;
    Some(fg::Timestamp::new(
        u32::try_from(s).unwrap_or(u32::MAX),
        (h.stamp_ns % 1_000_000_000) as u32,
    ))
}

fn planar_pose(x: f64, y: f64, theta: f64) -> fg::Pose {
    fg::Pose {
        position: Some(fg::Vector3 { x, y, z: 0.0 }),
        orientation: Some(yaw(theta)),
    }
}

fn yaw(theta: f64) -> fg::Quaternion {
    let h = theta / 2.0;
    fg::Quaternion {
        x: 0.0,
        y: 0.0,
        z: h.sin(),
        w: h.cos(),
    }
}

fn pb<M: prost::Message>(m: &M, out: &mut Vec<u8>) -> Result<(), String> {
    m.encode(out).map_err(|e| e.to_string())
}

impl FixedCodec for LaserScan {
    fn schema() -> SchemaDesc {
        wkt_schema::<fg::LaserScan>()
    }
    fn encode(&self, out: &mut Vec<u8>) -> Result<(), String> {
        let n = (self.count as usize).min(MAX_BEAMS);
        let last = self.angle_min + self.angle_increment * n.saturating_sub(1) as f32;
        pb(
            &fg::LaserScan {
                timestamp: timestamp(&self.header),
                frame_id: self.header.frame_id.as_str().to_string(),
                pose: Some(planar_pose(0.0, 0.0, 0.0)),
                start_angle: f64::from(self.angle_min),
                end_angle: f64::from(last),
                ranges: self.ranges[..n].iter().map(|r| f64::from(*r)).collect(),
                intensities: Vec::new(),
            },
            out,
        )?;
        append_trailer(raw_of(self), out)
    }
    fn decode(data: &[u8]) -> Result<Self, String> {
        from_raw(&trailer(data)?)
    }
}

impl FixedCodec for PoseWithCovariance {
    fn schema() -> SchemaDesc {
        wkt_schema::<fg::PoseInFrame>()
    }
    fn encode(&self, out: &mut Vec<u8>) -> Result<(), String> {
        pb(
            &fg::PoseInFrame {
                timestamp: timestamp(&self.header),
                frame_id: self.header.frame_id.as_str().to_string(),
                pose: Some(planar_pose(self.pose.x, self.pose.y, self.pose.theta)),
            },
            out,
        )?;
        append_trailer(raw_of(self), out)
    }
    fn decode(data: &[u8]) -> Result<Self, String> {
        from_raw(&trailer(data)?)
    }
}

impl FixedCodec for Odometry {
    fn schema() -> SchemaDesc {
        wkt_schema::<fg::FrameTransforms>()
    }
    fn encode(&self, out: &mut Vec<u8>) -> Result<(), String> {
        let parent = match self.header.frame_id.as_str() {
            "" => "odom",
            f => f,
        };
        let child = match self.child_frame_id.as_str() {
            "" => "base_link",
            f => f,
        };
        pb(
            &fg::FrameTransforms {
                transforms: vec![fg::FrameTransform {
                    timestamp: timestamp(&self.header),
                    parent_frame_id: parent.to_string(),
                    child_frame_id: child.to_string(),
                    translation: Some(fg::Vector3 {
                        x: self.pose.x,
                        y: self.pose.y,
                        z: 0.0,
                    }),
                    rotation: Some(yaw(self.pose.theta)),
                }],
            },
            out,
        )?;
        append_trailer(raw_of(self), out)
    }
    fn decode(data: &[u8]) -> Result<Self, String> {
        from_raw(&trailer(data)?)
    }
}

impl SliceCodec for GridInfo {
    fn schema() -> SchemaDesc {
        wkt_schema::<fg::Grid>()
    }
    fn encode(&self, data: &[i8], out: &mut Vec<u8>) -> Result<(), String> {
        let r = f64::from(self.resolution);
        pb(
            &fg::Grid {
                timestamp: timestamp(&self.header),
                frame_id: self.header.frame_id.as_str().to_string(),
                pose: Some(planar_pose(self.origin.x, self.origin.y, self.origin.theta)),
                column_count: self.width,
                cell_size: Some(fg::Vector2 { x: r, y: r }),
                row_stride: self.width,
                cell_stride: 1,
                fields: vec![fg::PackedElementField {
                    name: "occupancy".into(),
                    offset: 0,
                    r#type: fg::packed_element_field::NumericType::Int8 as i32,
                }],
                data: data.iter().map(|c| *c as u8).collect::<Vec<u8>>().into(),
            },
            out,
        )?;
        append_trailer(raw_of(self), out)
    }
    fn decode(data: &[u8]) -> Result<(Self, Vec<i8>), String> {
        let grid = fg::Grid::decode(data).map_err(|e| format!("protobuf: {e}"))?;
        let h = from_raw(&trailer(data)?)?;
        Ok((h, grid.data.iter().map(|b| *b as i8).collect()))
    }
}

impl SliceCodec for ImageInfo {
    fn schema() -> SchemaDesc {
        wkt_schema::<fg::RawImage>()
    }
    fn encode(&self, data: &[u8], out: &mut Vec<u8>) -> Result<(), String> {
        pb(
            &fg::RawImage {
                timestamp: timestamp(&self.header),
                frame_id: self.header.frame_id.as_str().to_string(),
                width: self.width,
                height: self.height,
                encoding: self.encoding.as_str().to_string(),
                step: self.step,
                data: data.to_vec().into(),
            },
            out,
        )?;
        append_trailer(raw_of(self), out)
    }
    fn decode(data: &[u8]) -> Result<(Self, Vec<u8>), String> {
        let img = fg::RawImage::decode(data).map_err(|e| format!("protobuf: {e}"))?;
        let h = from_raw(&trailer(data)?)?;
        Ok((h, img.data.to_vec()))
    }
}

/// hng's bytes of a slice message with no exact place in its well-known schema: the header
/// (field [`RAW_FIELD`]) and the payload's elements (field [`RAW_FIELD`] + 1).
#[derive(Clone, PartialEq, prost::Message)]
struct SliceTrailer {
    #[prost(bytes = "vec", tag = "15000")]
    raw: Vec<u8>,
    #[prost(bytes = "vec", tag = "15001")]
    data: Vec<u8>,
}

impl SliceCodec for PathInfo {
    fn schema() -> SchemaDesc {
        wkt_schema::<fg::PosesInFrame>()
    }
    fn encode(&self, data: &[Pose2D], out: &mut Vec<u8>) -> Result<(), String> {
        let frame = match self.header.frame_id.as_str() {
            "" => "map",
            f => f,
        };
        pb(
            &fg::PosesInFrame {
                timestamp: timestamp(&self.header),
                frame_id: frame.to_string(),
                poses: data
                    .iter()
                    .map(|p| planar_pose(p.x, p.y, p.theta))
                    .collect(),
            },
            out,
        )?;
        // The poses again as hng's bytes: a quaternion does not give back the heading's bits.
        pb(
            &SliceTrailer {
                raw: raw_of(self).to_vec(),
                data: elems_as_bytes(data).to_vec(),
            },
            out,
        )
    }
    fn decode(data: &[u8]) -> Result<(Self, Vec<Pose2D>), String> {
        let t = SliceTrailer::decode(data).map_err(|e| format!("protobuf: {e}"))?;
        if t.raw.is_empty() {
            return Err("no hng bytes (field 15000) in the message: not written by hng".into());
        }
        Ok((from_raw(&t.raw)?, elems_from_bytes(&t.data)?))
    }
}

/// A JSON Schema describing `v` (objects, arrays, numbers, strings, booleans).
pub(crate) fn infer_schema(v: &Value) -> Value {
    match v {
        Value::Null => Value::Object(Map::new()),
        Value::Bool(_) => serde_json::json!({"type": "boolean"}),
        Value::Number(_) => serde_json::json!({"type": "number"}),
        Value::String(_) => serde_json::json!({"type": "string"}),
        Value::Array(a) => serde_json::json!({
            "type": "array",
            "items": a.first().map(infer_schema).unwrap_or_else(|| Value::Object(Map::new())),
        }),
        Value::Object(o) => {
            let props: Map<String, Value> = o
                .iter()
                .map(|(k, v)| (k.clone(), infer_schema(v)))
                .collect();
            serde_json::json!({"type": "object", "properties": props})
        }
    }
}

/// The JSON Schema of a JSON-encoded hng type: its default value's shape plus the raw fields.
pub(crate) fn json_schema(type_name: &str, sample: Value, slice: bool) -> SchemaDesc {
    let mut s = infer_schema(&sample);
    if let Some(p) = s.get_mut("properties").and_then(Value::as_object_mut) {
        let b64 = serde_json::json!({"type": "string", "contentEncoding": "base64"});
        p.insert("hng_raw".into(), b64.clone());
        if slice {
            p.insert("hng_data".into(), b64);
        }
    }
    if let Some(o) = s.as_object_mut() {
        o.insert(
            "$schema".into(),
            "https://json-schema.org/draft/2020-12/schema".into(),
        );
        o.insert("title".into(), type_name.into());
    }
    SchemaDesc {
        name: type_name.to_string(),
        encoding: "jsonschema",
        data: serde_json::to_vec(&s).unwrap_or_default(),
        message_encoding: "json",
    }
}

fn json_object<T: serde::Serialize>(v: &T) -> Result<Map<String, Value>, String> {
    match serde_json::to_value(v).map_err(|e| e.to_string())? {
        Value::Object(o) => Ok(o),
        other => {
            let mut o = Map::new();
            o.insert("value".into(), other);
            Ok(o)
        }
    }
}

fn b64_field(o: &Value, key: &str) -> Result<Vec<u8>, String> {
    let s = o
        .get(key)
        .and_then(Value::as_str)
        .ok_or_else(|| format!("no {key:?} in the message: not written by hng"))?;
    B64.decode(s).map_err(|e| format!("{key}: {e}"))
}

/// JSON encoding of a fixed-size type.
pub(crate) fn json_encode_fixed<T: Message>(v: &T, out: &mut Vec<u8>) -> Result<(), String> {
    let mut o = json_object(v)?;
    o.insert("hng_raw".into(), B64.encode(raw_of(v)).into());
    serde_json::to_writer(out, &o).map_err(|e| e.to_string())
}

/// JSON encoding of a fixed-size type without a serde form: its header and its bytes.
pub(crate) fn json_encode_raw<T: Message>(v: &T, out: &mut Vec<u8>) -> Result<(), String> {
    let mut o = Map::new();
    o.insert(
        "header".into(),
        serde_json::to_value(v.header()).map_err(|e| e.to_string())?,
    );
    o.insert("hng_raw".into(), B64.encode(raw_of(v)).into());
    serde_json::to_writer(out, &o).map_err(|e| e.to_string())
}

/// A fixed-size type back from its JSON encoding.
pub(crate) fn json_decode_fixed<T: Message>(data: &[u8]) -> Result<T, String> {
    let v: Value = serde_json::from_slice(data).map_err(|e| format!("JSON: {e}"))?;
    from_raw(&b64_field(&v, "hng_raw")?)
}

fn elems_as_bytes<E: Copy>(data: &[E]) -> &[u8] {
    // SAFETY: slice elements are plain data (u8, i8, ...); the byte view covers the slice.
    unsafe { std::slice::from_raw_parts(data.as_ptr().cast::<u8>(), std::mem::size_of_val(data)) }
}

fn elems_from_bytes<E: Copy + Default>(b: &[u8]) -> Result<Vec<E>, String> {
    let n = size_of::<E>().max(1);
    if !b.len().is_multiple_of(n) {
        return Err(format!(
            "{} payload bytes are not a whole number of {n}-byte elements",
            b.len()
        ));
    }
    b.chunks_exact(n).map(from_raw::<E>).collect()
}

/// JSON encoding of a slice type: its header's serde form, `len`, and for JSON documents the
/// document itself.
pub(crate) fn json_encode_slice<H: SliceMessage>(
    h: &H,
    data: &[H::Elem],
    document: bool,
    out: &mut Vec<u8>,
) -> Result<(), String> {
    let mut o = json_object(h)?;
    o.insert("len".into(), data.len().into());
    let bytes = elems_as_bytes(data);
    if document {
        o.insert(
            "document".into(),
            serde_json::from_slice::<Value>(bytes).unwrap_or(Value::Null),
        );
    }
    o.insert("hng_raw".into(), B64.encode(raw_of(h)).into());
    o.insert("hng_data".into(), B64.encode(bytes).into());
    serde_json::to_writer(out, &o).map_err(|e| e.to_string())
}

/// JSON encoding of a contract control message: [`json_encode_slice`]'s fields and the
/// envelope decoded (`envelope`), or why it does not decode (`envelope_error`), so the
/// contract protocol reads in any MCAP viewer.
pub(crate) fn json_encode_control(
    h: &ControlInfo,
    data: &[u8],
    out: &mut Vec<u8>,
) -> Result<(), String> {
    let mut o = json_object(h)?;
    o.insert("len".into(), data.len().into());
    match wire::decode(data) {
        Ok(env) => {
            o.insert(
                "envelope".into(),
                serde_json::to_value(&env).map_err(|e| e.to_string())?,
            );
        }
        Err(e) => {
            o.insert("envelope_error".into(), e.to_string().into());
        }
    }
    o.insert("hng_raw".into(), B64.encode(raw_of(h)).into());
    o.insert("hng_data".into(), B64.encode(data).into());
    serde_json::to_writer(out, &o).map_err(|e| e.to_string())
}

/// A slice type back from its JSON encoding.
pub(crate) fn json_decode_slice<H: SliceMessage>(data: &[u8]) -> Result<(H, Vec<H::Elem>), String> {
    let v: Value = serde_json::from_slice(data).map_err(|e| format!("JSON: {e}"))?;
    let h = from_raw(&b64_field(&v, "hng_raw")?)?;
    let d = elems_from_bytes(&b64_field(&v, "hng_data")?)?;
    Ok((h, d))
}

#[cfg(test)]
mod tests {
    use super::*;
    use hng_runtime::msg::{FrameId, Pose2D, Twist};

    #[test]
    fn scans_round_trip_and_decode_as_foxglove() {
        let mut s = LaserScan {
            angle_min: -1.5,
            angle_increment: 0.01,
            range_max: 12.0,
            count: 300,
            ..Default::default()
        };
        s.header.stamp_ns = 2_500_000_001;
        s.header.frame_id = FrameId::LASER;
        s.ranges[7] = 3.25;
        let mut buf = Vec::new();
        FixedCodec::encode(&s, &mut buf).unwrap();
        let back = <LaserScan as FixedCodec>::decode(&buf).unwrap();
        assert_eq!(raw_of(&back), raw_of(&s));
        let fgs = fg::LaserScan::decode(buf.as_slice()).unwrap();
        assert_eq!(fgs.ranges.len(), 300);
        assert_eq!(fgs.ranges[7], 3.25);
        assert_eq!(fgs.frame_id, "laser");
        assert_eq!(fgs.timestamp.unwrap().sec(), 2);
    }

    #[test]
    fn contract_messages_are_recorded_with_their_envelope_decoded() {
        use hng_runtime::contract::ModuleId;
        use hng_runtime::contract::wire::{Envelope, Message, Propose};
        let env = Envelope {
            from: ModuleId(7),
            body: Message::Propose(Propose {
                query_id: 3,
                need: 1,
                value: 0.75,
                channel: "7/Localization".into(),
            }),
        };
        let bytes = wire::encode(&env).unwrap();
        let mut buf = Vec::new();
        json_encode_control(&ControlInfo::default(), &bytes, &mut buf).unwrap();
        let v: Value = serde_json::from_slice(&buf).unwrap();
        assert_eq!(v["envelope"]["from"], 7);
        assert_eq!(v["envelope"]["body"]["Propose"]["value"], 0.75);
        assert_eq!(v["len"], bytes.len());
        let (_, back) = json_decode_slice::<ControlInfo>(&buf).unwrap();
        assert_eq!(back, bytes, "the bytes come back for a replay");
        // Bytes that are no envelope are recorded with the reason, never lost.
        buf.clear();
        json_encode_control(&ControlInfo::default(), b"xy", &mut buf).unwrap();
        let v: Value = serde_json::from_slice(&buf).unwrap();
        assert!(v["envelope_error"].as_str().is_some_and(|e| !e.is_empty()));
        assert!(v.get("envelope").is_none());
    }

    #[test]
    fn json_types_round_trip_with_a_schema() {
        let t = Twist {
            linear_x: 0.5,
            angular_z: -0.25,
            ..Default::default()
        };
        let mut buf = Vec::new();
        json_encode_fixed(&t, &mut buf).unwrap();
        let v: Value = serde_json::from_slice(&buf).unwrap();
        assert_eq!(v["linear_x"], 0.5);
        let back: Twist = json_decode_fixed(&buf).unwrap();
        assert_eq!(back.linear_x, 0.5);
        let s = json_schema(
            "hng/Twist/v1",
            serde_json::to_value(Twist::default()).unwrap(),
            false,
        );
        let schema: Value = serde_json::from_slice(&s.data).unwrap();
        assert_eq!(schema["properties"]["angular_z"]["type"], "number");
        assert_eq!(schema["properties"]["hng_raw"]["type"], "string");
    }

    #[test]
    fn grids_keep_cells_and_origin() {
        let h = GridInfo {
            resolution: 0.05,
            width: 3,
            height: 2,
            origin: Pose2D::new(-1.0, 2.0, 0.0),
            ..Default::default()
        };
        let cells = [0i8, 100, -1, 50, 0, 0];
        let mut buf = Vec::new();
        h.encode(&cells, &mut buf).unwrap();
        let (h2, c2) = <GridInfo as SliceCodec>::decode(&buf).unwrap();
        assert_eq!(h2.width, 3);
        assert_eq!(c2, cells);
    }

    #[test]
    fn paths_are_foxglove_poses_in_frame_and_come_back_bit_exact() {
        let mut h = PathInfo {
            goal_id: 3,
            length_m: 2.5,
            ..Default::default()
        };
        h.header.frame_id = FrameId::MAP;
        h.header.stamp_ns = 7_000_000_123;
        let poses = [Pose2D::new(0.1, -0.2, 0.3), Pose2D::new(1.0, 2.0, -3.1)];
        let mut buf = Vec::new();
        h.encode(&poses, &mut buf).unwrap();
        let fgp = fg::PosesInFrame::decode(buf.as_slice()).unwrap();
        assert_eq!(fgp.frame_id, "map");
        assert_eq!(fgp.poses.len(), 2);
        let p = fgp.poses[1].position.unwrap();
        assert_eq!((p.x, p.y), (1.0, 2.0));
        let q = fgp.poses[1].orientation.unwrap();
        assert!((2.0 * q.z.atan2(q.w) - (-3.1)).abs() < 1e-9);
        let (h2, p2) = <PathInfo as SliceCodec>::decode(&buf).unwrap();
        assert_eq!(raw_of(&h2), raw_of(&h));
        assert_eq!(p2, poses);
    }

    #[test]
    fn foreign_messages_are_refused_with_a_reason() {
        let mut buf = Vec::new();
        prost::Message::encode(&fg::PoseInFrame::default(), &mut buf).unwrap();
        let e = <PoseWithCovariance as FixedCodec>::decode(&buf).unwrap_err();
        assert!(e.contains("15000"), "{e}");
        let e = json_decode_fixed::<Twist>(b"{\"linear_x\": 1}").unwrap_err();
        assert!(e.contains("hng_raw"), "{e}");
    }
}
