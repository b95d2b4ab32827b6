// The live-view test's independent client: FoxgloveClient of the npm package
// @foxglove/ws-protocol, on a `ws` socket that offers the subprotocol the Foxglove SDK's server
// speaks (foxglove.sdk.v1). It subscribes to TOPIC, decodes WANT messages with the schema the
// server advertised (a protobuf FileDescriptorSet, or JSON) and prints one JSON object.
//
// Usage: node client.mjs ws://127.0.0.1:PORT TOPIC [WANT] [TIMEOUT_MS]
import wsProtocol from "@foxglove/ws-protocol";
import protobuf from "protobufjs";
import descriptor from "protobufjs/ext/descriptor/index.js";
import WebSocket from "ws";

const { FoxgloveClient } = wsProtocol;

const [url, topic, wantArg, timeoutArg] = process.argv.slice(2);
const want = Number(wantArg ?? 5);
const timer = setTimeout(() => {
  console.error(`timeout: ${out.messages.length} of ${want} message(s) on ${topic}; advertised: ${JSON.stringify(seen)}`);
  process.exit(2);
}, Number(timeoutArg ?? 20000));

const out = { topic, schemaName: null, encoding: null, messages: [] };
const seen = [];
const decoders = new Map();
const client = new FoxgloveClient({ ws: new WebSocket(url, ["foxglove.sdk.v1"]) });

client.on("error", (e) => {
  console.error(`client error: ${e?.message ?? e}`);
  process.exit(3);
});

client.on("advertise", (channels) => {
  for (const ch of channels) {
    seen.push(ch.topic);
    if (ch.topic !== topic) continue;
    out.schemaName = ch.schemaName;
    out.encoding = ch.encoding;
    let decode;
    if (ch.encoding === "protobuf") {
      const fds = descriptor.FileDescriptorSet.decode(Buffer.from(ch.schema, "base64"));
      const type = protobuf.Root.fromDescriptor(fds).lookupType(ch.schemaName);
      decode = (data) => type.toObject(type.decode(data), { longs: Number, defaults: true });
    } else if (ch.encoding === "json") {
      decode = (data) => JSON.parse(new TextDecoder().decode(data));
    } else {
      console.error(`unsupported encoding ${ch.encoding}`);
      process.exit(4);
    }
    decoders.set(client.subscribe(ch.id), decode);
  }
});

client.on("message", ({ subscriptionId, data }) => {
  const decode = decoders.get(subscriptionId);
  if (!decode) return;
  const m = decode(new Uint8Array(data.buffer, data.byteOffset, data.byteLength));
  out.messages.push({
    frame_id: m.frameId ?? m.frame_id,
    ranges: m.ranges?.length ?? null,
    start_angle: m.startAngle ?? m.start_angle ?? null,
    end_angle: m.endAngle ?? m.end_angle ?? null,
    sec: m.timestamp?.sec ?? null,
  });
  if (out.messages.length >= want) {
    clearTimeout(timer);
    console.log(JSON.stringify(out));
    client.close();
    process.exit(0);
  }
});
