//! The message types the recorder knows, by iceoryx2 type name: how to subscribe to a
//! channel of each (recording) and publish on one (replay).

use hng_runtime::channel::{
    ChannelStats, Node, Publisher, SlicePublisher, SliceSubscriber, Subscriber,
};
use hng_runtime::control::ControlInfo;
use hng_runtime::msg::{self, Header, SliceMessage};
use hng_runtime::system;
use iceoryx2::prelude::ZeroCopySend;

use crate::codec::{self, FixedCodec, SchemaDesc, SliceCodec};

/// The iceoryx2 type name of `T` (`hng/LaserScan/v1`).
pub fn type_name<T: ZeroCopySend>() -> String {
    // SAFETY: only unsafe because implementors may lie; hng's are derived.
    unsafe { <T as ZeroCopySend>::type_name() }.to_string()
}

/// Where a tap hands each encoded message, with its header.
pub(crate) type Sink<'a> = dyn FnMut(&Header, &[u8]) -> Result<(), crate::Error> + 'a;
type OpenTap = fn(&Node, &str) -> Result<Box<dyn Tap>, hng_runtime::Error>;
type OpenOutlet = fn(&Node, &str) -> Result<Box<dyn Outlet>, hng_runtime::Error>;

/// What a subscribed channel hands the recorder.
pub(crate) trait Tap {
    /// Encodes every waiting message and hands it to `sink` with its header.
    fn drain(&mut self, sink: &mut Sink<'_>) -> Result<u64, crate::Error>;
    /// The subscriber's counters (drops from sequence gaps).
    fn stats(&self) -> ChannelStats;
}

/// A replay publisher: decodes recorded messages and publishes them as recorded.
pub(crate) trait Outlet {
    /// Publishes the message encoded in `data`; returns its header.
    fn publish(&self, data: &[u8]) -> Result<Header, String>;
}

/// One known type.
pub struct TypeEntry {
    /// The iceoryx2 type name (for slices: the header's).
    pub type_name: String,
    /// The channel kind of the type (fixes its QoS).
    pub kind: hng_runtime::qos::ChannelKind,
    /// The schema a channel of this type is written with.
    pub schema: fn() -> SchemaDesc,
    pub(crate) tap: OpenTap,
    pub(crate) outlet: OpenOutlet,
    pub(crate) decode_header: fn(&[u8]) -> Result<Header, String>,
}

struct FixedTap<T: FixedCodec> {
    sub: Subscriber<T>,
    buf: Vec<u8>,
}

impl<T: FixedCodec> Tap for FixedTap<T> {
    fn drain(&mut self, sink: &mut Sink<'_>) -> Result<u64, crate::Error> {
        let mut n = 0;
        while let Some(s) = self.sub.receive()? {
            self.buf.clear();
            FixedCodec::encode(&*s, &mut self.buf).map_err(|detail| crate::Error::Codec {
                channel: self.sub.channel().to_string(),
                detail,
            })?;
            sink(s.header(), &self.buf)?;
            n += 1;
        }
        Ok(n)
    }
    fn stats(&self) -> ChannelStats {
        self.sub.stats()
    }
}

struct SliceTap<H: SliceCodec> {
    sub: SliceSubscriber<H>,
    buf: Vec<u8>,
}

impl<H: SliceCodec> Tap for SliceTap<H> {
    fn drain(&mut self, sink: &mut Sink<'_>) -> Result<u64, crate::Error> {
        let mut n = 0;
        while let Some(s) = self.sub.receive()? {
            self.buf.clear();
            s.header()
                .encode(s.data(), &mut self.buf)
                .map_err(|detail| crate::Error::Codec {
                    channel: self.sub.channel().to_string(),
                    detail,
                })?;
            sink(SliceMessage::header(s.header()), &self.buf)?;
            n += 1;
        }
        Ok(n)
    }
    fn stats(&self) -> ChannelStats {
        self.sub.stats()
    }
}

struct FixedOutlet<T: FixedCodec>(Publisher<T>);

impl<T: FixedCodec> Outlet for FixedOutlet<T> {
    fn publish(&self, data: &[u8]) -> Result<Header, String> {
        let m = T::decode(data)?;
        let h = *m.header();
        self.0.publish_recorded(m).map_err(|e| e.to_string())?;
        Ok(h)
    }
}

struct SliceOutlet<H: SliceCodec>(SlicePublisher<H>);

impl<H: SliceCodec> Outlet for SliceOutlet<H> {
    fn publish(&self, data: &[u8]) -> Result<Header, String> {
        let (h, d) = H::decode(data)?;
        let hd = *SliceMessage::header(&h);
        self.0.publish_recorded(h, &d).map_err(|e| e.to_string())?;
        Ok(hd)
    }
}

fn fixed<T: FixedCodec>() -> TypeEntry {
    TypeEntry {
        type_name: type_name::<T>(),
        kind: T::KIND,
        schema: T::schema,
        tap: |node, ch| {
            Ok(Box::new(FixedTap::<T> {
                sub: node.tap_subscriber::<T>(ch)?,
                buf: Vec::new(),
            }) as Box<dyn Tap>)
        },
        outlet: |node, ch| {
            Ok(Box::new(FixedOutlet::<T>(node.publisher::<T>(ch)?)) as Box<dyn Outlet>)
        },
        decode_header: |data| T::decode(data).map(|m| *m.header()),
    }
}

fn slice<H: SliceCodec>() -> TypeEntry {
    TypeEntry {
        type_name: type_name::<H>(),
        kind: H::KIND,
        schema: H::schema,
        tap: |node, ch| {
            Ok(Box::new(SliceTap::<H> {
                sub: node.slice_tap_subscriber::<H>(ch)?,
                buf: Vec::new(),
            }) as Box<dyn Tap>)
        },
        outlet: |node, ch| {
            Ok(Box::new(SliceOutlet::<H>(node.slice_publisher::<H>(ch, 4096)?)) as Box<dyn Outlet>)
        },
        decode_header: |data| H::decode(data).map(|(h, _)| *SliceMessage::header(&h)),
    }
}

/// JSON-encoded fixed-size types.
macro_rules! json_fixed {
    ($($t:ty),* $(,)?) => {$(
        impl FixedCodec for $t {
            fn schema() -> SchemaDesc {
                codec::json_schema(
                    &type_name::<$t>(),
                    serde_json::to_value(<$t>::default()).unwrap_or_default(),
                    false,
                )
            }
            fn encode(&self, out: &mut Vec<u8>) -> Result<(), String> {
                codec::json_encode_fixed(self, out)
            }
            fn decode(data: &[u8]) -> Result<Self, String> {
                codec::json_decode_fixed(data)
            }
        }
    )*};
}

/// JSON-encoded slice types (`true`: the payload is a JSON document).
macro_rules! json_slice {
    ($($t:ty => $doc:expr),* $(,)?) => {$(
        impl SliceCodec for $t {
            fn schema() -> SchemaDesc {
                let mut sample = serde_json::to_value(<$t>::default()).unwrap_or_default();
                if let Some(o) = sample.as_object_mut() {
                    o.insert("len".into(), 0.into());
                    if $doc {
                        o.insert("document".into(), serde_json::Value::Null);
                    }
                }
                codec::json_schema(&type_name::<$t>(), sample, true)
            }
            fn encode(&self, data: &[Self::Elem], out: &mut Vec<u8>) -> Result<(), String> {
                codec::json_encode_slice(self, data, $doc, out)
            }
            fn decode(data: &[u8]) -> Result<(Self, Vec<Self::Elem>), String> {
                codec::json_decode_slice(data)
            }
        }
    )*};
}

json_fixed!(
    msg::Twist,
    msg::BeaconObservation,
    msg::Goal,
    msg::Waypoint,
    msg::Clock,
    hng_runtime::clock::lockstep::ClockAck,
    msg::ModuleReport,
    system::SupervisorCommand,
    system::ModuleEvent,
    system::ResourceCosts,
    system::EffectiveCosts,
    system::ContractTable,
    hng_simulator::module::SimStatus,
    hng_simulator::module::SimCollision,
    hng_modules::msgs::GoalStatus,
    hng_modules::msgs::Mission,
    hng_modules::msgs::MissionStatus,
    msg::BeaconTrack,
    msg::Designation,
    hng_modules::reacher_module::ReachStatus,
    hng_simulator::module::SimLighting,
    hng_simulator::module::SimTeleport,
);

/// JSON-encoded fixed-size types without a serde form: the header and the bytes only.
macro_rules! raw_fixed {
    ($($t:ty),* $(,)?) => {$(
        impl FixedCodec for $t {
            fn schema() -> SchemaDesc {
                let sample = serde_json::json!({ "header": msg::Header::default() });
                codec::json_schema(&type_name::<$t>(), sample, false)
            }
            fn encode(&self, out: &mut Vec<u8>) -> Result<(), String> {
                codec::json_encode_raw(self, out)
            }
            fn decode(data: &[u8]) -> Result<Self, String> {
                codec::json_decode_fixed(data)
            }
        }
    )*};
}

json_fixed!(
    msg::FollowWallRequest,
    hng_modules::planning::progress::NavProgress,
);

raw_fixed!(
    msg::Walls,
    msg::Behaviours,
    msg::Order,
    msg::OrderStatus,
    msg::SpeedEnvelope
);

json_slice!(system::JsonInfo => true, msg::BytesInfo => false);

/// Contract control messages: JSON with the envelope decoded (never replayed by default:
/// `hng/...` channels are system channels).
impl SliceCodec for ControlInfo {
    fn schema() -> SchemaDesc {
        let mut sample = serde_json::to_value(ControlInfo::default()).unwrap_or_default();
        if let Some(o) = sample.as_object_mut() {
            o.insert("len".into(), 0.into());
        }
        codec::json_schema(&type_name::<ControlInfo>(), sample, true)
    }
    fn encode(&self, data: &[u8], out: &mut Vec<u8>) -> Result<(), String> {
        codec::json_encode_control(self, data, out)
    }
    fn decode(data: &[u8]) -> Result<(Self, Vec<u8>), String> {
        codec::json_decode_slice(data)
    }
}

/// What is done with each known type ([`visit_known_types`]): a generic function per kind.
pub trait KnownTypes {
    /// A fixed-size message type.
    fn fixed<T: FixedCodec>(&mut self);
    /// A slice message type (header and payload).
    fn slice<H: SliceCodec>(&mut self);
}

/// Calls `v` with every type the recorder knows (the one list: `hng topic` prints the same
/// types).
pub fn visit_known_types(v: &mut impl KnownTypes) {
    v.fixed::<msg::LaserScan>();
    v.fixed::<msg::Odometry>();
    v.fixed::<msg::PoseWithCovariance>();
    v.fixed::<msg::Twist>();
    v.fixed::<msg::BeaconObservation>();
    v.fixed::<msg::Goal>();
    v.fixed::<msg::Waypoint>();
    v.fixed::<msg::Clock>();
    v.fixed::<hng_runtime::clock::lockstep::ClockAck>();
    v.fixed::<msg::ModuleReport>();
    v.fixed::<system::SupervisorCommand>();
    v.fixed::<system::ModuleEvent>();
    v.fixed::<system::ResourceCosts>();
    v.fixed::<system::EffectiveCosts>();
    v.fixed::<system::ContractTable>();
    v.fixed::<hng_simulator::module::SimStatus>();
    v.fixed::<hng_simulator::module::SimCollision>();
    v.fixed::<hng_modules::msgs::GoalStatus>();
    v.fixed::<hng_modules::msgs::Mission>();
    v.fixed::<hng_modules::msgs::MissionStatus>();
    v.fixed::<msg::BeaconTrack>();
    v.fixed::<msg::Designation>();
    v.fixed::<hng_modules::reacher_module::ReachStatus>();
    v.fixed::<hng_simulator::module::SimLighting>();
    v.fixed::<hng_simulator::module::SimTeleport>();
    v.fixed::<msg::FollowWallRequest>();
    v.fixed::<hng_modules::planning::progress::NavProgress>();
    v.fixed::<msg::Walls>();
    v.fixed::<msg::Behaviours>();
    v.fixed::<msg::Order>();
    v.fixed::<msg::OrderStatus>();
    v.fixed::<msg::SpeedEnvelope>();
    v.slice::<msg::PathInfo>();
    v.slice::<msg::GridInfo>();
    v.slice::<msg::ImageInfo>();
    v.slice::<msg::BytesInfo>();
    v.slice::<system::JsonInfo>();
    v.slice::<ControlInfo>();
}

/// Every type the recorder knows.
pub fn registry() -> Vec<TypeEntry> {
    struct Entries(Vec<TypeEntry>);
    impl KnownTypes for Entries {
        fn fixed<T: FixedCodec>(&mut self) {
            self.0.push(fixed::<T>());
        }
        fn slice<H: SliceCodec>(&mut self) {
            self.0.push(slice::<H>());
        }
    }
    let mut entries = Entries(Vec::new());
    visit_known_types(&mut entries);
    entries.0
}

/// The entry of a type name.
pub fn lookup<'a>(reg: &'a [TypeEntry], type_name: &str) -> Option<&'a TypeEntry> {
    reg.iter().find(|e| e.type_name == type_name)
}
