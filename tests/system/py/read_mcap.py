"""The recording test's independent reader: the PyPI `mcap` package with
`mcap-protobuf-support` reads an hng recording, decodes every message with the schema the file
names (protobuf for Foxglove's well-known schemas, JSON otherwise) and prints, as one JSON
object, each channel's schema, encoding and message count, and what it checked while decoding.

Usage: python read_mcap.py [--partial] FILE.mcap

--partial: the file may be cut short (a full disk): read it front to back without its summary
(mcap's StreamReader) and stop at the first record that cannot be read, counting the
messages before it.
"""

import json
import sys

from mcap.decoder import DecoderFactory
from mcap.reader import make_reader
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoderFactory


class JsonDecoderFactory(DecoderFactory):
    """Messages with message encoding `json`."""

    def decoder_for(self, message_encoding, schema):
        if message_encoding != "json":
            return None
        return lambda data: json.loads(data)


def main(path):
    out = {
        "channels": {},
        "decoded": 0,
        "scans_with_ranges": 0,
        "poses_with_position": 0,
        "logs_with_text": 0,
        "paths_with_poses": 0,
        "attachments": {},
    }
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[ProtobufDecoderFactory(), JsonDecoderFactory()])
        summary = reader.get_summary()
        schemas = summary.schemas
        for ch in summary.channels.values():
            schema = schemas.get(ch.schema_id)
            out["channels"][ch.topic] = {
                "messages": 0,
                "schema": schema.name if schema else "",
                "message_encoding": ch.message_encoding,
            }
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            out["channels"][channel.topic]["messages"] += 1
            out["decoded"] += 1
            if schema.name == "foxglove.LaserScan" and len(decoded.ranges) > 0:
                out["scans_with_ranges"] += 1
            if schema.name == "foxglove.PoseInFrame" and decoded.HasField("pose"):
                out["poses_with_position"] += 1
            if schema.name == "foxglove.Log" and decoded.message and decoded.name:
                out["logs_with_text"] += 1
            if schema.name == "foxglove.PosesInFrame" and len(decoded.poses) > 0:
                out["paths_with_poses"] += 1
        out["metadata"] = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        for a in reader.iter_attachments():
            out["attachments"][a.name] = out["attachments"].get(a.name, 0) + 1
    print(json.dumps(out))


def partial(path):
    out = {"channels": {}, "decoded": 0, "error": None}
    factories = [ProtobufDecoderFactory(), JsonDecoderFactory()]
    schemas, channels, decoders = {}, {}, {}
    with open(path, "rb") as f:
        try:
            for r in StreamReader(f, emit_chunks=False).records:
                if isinstance(r, Schema):
                    schemas[r.id] = r
                elif isinstance(r, Channel):
                    channels[r.id] = r
                elif isinstance(r, Message):
                    ch = channels[r.channel_id]
                    if ch.id not in decoders:
                        schema = schemas.get(ch.schema_id)
                        decoders[ch.id] = next(
                            d
                            for d in (fa.decoder_for(ch.message_encoding, schema) for fa in factories)
                            if d is not None
                        )
                    decoders[ch.id](r.data)
                    c = out["channels"].setdefault(ch.topic, {"messages": 0})
                    c["messages"] += 1
                    out["decoded"] += 1
        except Exception as e:  # the damaged end: what precedes it was read
            out["error"] = f"{type(e).__name__}: {e}"
    print(json.dumps(out))


if __name__ == "__main__":
    if sys.argv[1] == "--partial":
        partial(sys.argv[2])
    else:
        main(sys.argv[1])
