"""Reading a recording back with the ``mcap`` reader, also one whose writer was killed (no summary, a chunk cut
short): every record up to the first one that is not whole is read, and the recording says it ended early.

``read_messages(path)`` gives the file's metadata and its messages in file order, decoded: JSON channels as dicts,
Foxglove's well-known (protobuf) schemas by ``mcap-protobuf-support``; poses also as ``(x, y, yaw)``.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

from runtime.errors import InputError


@dataclass
class Message:
    topic: str
    schema: str
    ns: int                  # log time, ns
    data: object             # dict (JSON channels) or the decoded protobuf message

    @property
    def robot(self) -> int | None:
        """N of a ``/robot_N/...`` topic, else None."""
        parts = self.topic.split("/")
        if len(parts) == 3 and parts[1].startswith("robot_") and parts[1][6:].isdigit():
            return int(parts[1][6:])
        return None

    @property
    def kind(self) -> str:
        """The last part of the topic (``pose`` of ``/robot_1/pose``)."""
        return self.topic.rsplit("/", 1)[-1]

    @property
    def is_pose(self) -> bool:
        return self.schema == "foxglove.PoseInFrame" and not isinstance(self.data, (bytes, dict))

    @property
    def pose(self) -> tuple[float, float, float]:
        """(x, y, yaw) of a ``foxglove.PoseInFrame``."""
        p = self.data.pose
        q = p.orientation
        return p.position.x, p.position.y, 2.0 * math.atan2(q.z, q.w)


@dataclass
class Recording:
    source: str
    messages: list[Message] = field(default_factory=list)
    metadata: dict[str, dict] = field(default_factory=dict)
    channels: dict[str, str] = field(default_factory=dict)      # topic -> schema name
    truncated: str | None = None      # why the file ended early (a killed writer), None if whole
    dropped: int = 0                  # messages that would not decode (left out)


def _unavailable() -> InputError:
    return InputError("reading a recording needs mcap and mcap-protobuf-support: pip install 'mrta-runtime[record]'")


def _decode(data: bytes, ch, sch, decoders: dict, factory):
    if ch.message_encoding == "json":
        return json.loads(data)
    if ch.id not in decoders:
        decoders[ch.id] = factory.decoder_for(ch.message_encoding, sch)
    dec = decoders[ch.id]
    return dec(data) if dec is not None else data


def read_messages(path: str | Path, topics=None, decode: bool = True) -> Recording:
    """The recording at ``path``: metadata and messages (only ``topics`` if given), decoded unless ``decode`` is
    False (then ``data`` is the raw bytes).  A file that is not MCAP is an InputError naming it."""
    try:
        from mcap.records import Channel, Message as McapMessage, Metadata, Schema
        from mcap.stream_reader import StreamReader
        from mcap_protobuf.decoder import DecoderFactory
    except ImportError:
        raise _unavailable() from None
    source = str(path)
    out = Recording(source)
    schemas: dict[int, object] = {}
    chans: dict[int, object] = {}
    decoders: dict[int, object] = {}
    factory = DecoderFactory()
    wanted = None if topics is None else set(topics)
    try:
        fh = open(path, "rb")
    except OSError as exc:
        raise InputError(f"{source}: expected a recording (MCAP) that can be read ({exc.strerror})") from None
    with fh:
        reader = StreamReader(fh, skip_magic=False, validate_crcs=True)   # a flipped bit ends the read
        records = iter(reader.records)
        while True:
            try:
                rec = next(records)
            except StopIteration:
                break
            except Exception as exc:        # a record cut short (struct, zstd, lz4 errors), bad magic
                if not out.messages and not schemas and not out.metadata:
                    raise InputError(f"{source}: expected an MCAP recording ({type(exc).__name__}: {exc})") from None
                out.truncated = f"{type(exc).__name__}: {exc}"
                break
            if isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                chans[rec.id] = rec
                sch = schemas.get(rec.schema_id)
                out.channels[rec.topic] = sch.name if sch is not None else ""
            elif isinstance(rec, Metadata):
                out.metadata[rec.name] = dict(rec.metadata)
            elif isinstance(rec, McapMessage):
                ch = chans.get(rec.channel_id)
                if ch is None or (wanted is not None and ch.topic not in wanted):
                    continue
                sch = schemas.get(ch.schema_id)
                data: object = rec.data
                if decode:
                    try:
                        data = _decode(rec.data, ch, sch, decoders, factory)
                    except Exception:         # a JSON or protobuf payload that does not parse: counted, left out
                        out.dropped += 1
                        continue
                out.messages.append(Message(ch.topic, sch.name if sch is not None else "", rec.log_time, data))
    return out
