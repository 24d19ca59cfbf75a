"""A session log checked by readers that are not the project's: the `mcap` package reads it, `jsonschema` checks
every JSON message against the schema embedded in the log, protobuf parses every protobuf message with the
FileDescriptorSet embedded in the log, and the scene messages are checked against Foxglove's published schemas
(the `foxglove-schemas-protobuf` package: same message names, field names, numbers and types, and the bytes
parse with Foxglove's own compiled classes). Nothing from `common` is imported here."""

from __future__ import annotations

import collections
import json
import struct

import jsonschema
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.reader import make_reader

from .live import assert_nothing_left, start_up

pytestmark = pytest.mark.live


@pytest.fixture(scope="module")
def maze_log(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("indep")
    launch = start_up(tmp, "indep", "--env", "maze-pomdp", "--layout", "2", "--episodes", "6", "--seed", "1")
    assert launch.wait(timeout=300) == 0, launch.out
    assert_nothing_left(launch.rundir)
    return launch.rundir / "session.mcap"


def _protobuf_class(schema):
    pool = descriptor_pool.DescriptorPool()
    for f in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))


def _fields(descriptor) -> list[tuple]:
    return sorted((f.name, f.number, f.type, f.is_repeated) for f in descriptor.fields)


def _same_as_published(ours, published, seen=None) -> None:
    """Every message type reachable from `ours` has the published type's fields (name, number, type, repeated)."""
    seen = set() if seen is None else seen
    if ours.full_name in seen:
        return
    seen.add(ours.full_name)
    assert ours.full_name == published.full_name
    assert _fields(ours) == _fields(published), ours.full_name
    for f in ours.fields:
        if f.message_type is not None:
            _same_as_published(f.message_type, published.fields_by_name[f.name].message_type, seen)


def test_every_message_matches_its_embedded_schema_and_the_scene_matches_foxglove(maze_log):
    with open(maze_log, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None  # a finished file
        validators, classes, counts = {}, {}, collections.Counter()
        for schema, channel, message in reader.iter_messages():
            counts[channel.topic] += 1
            assert "indep" not in channel.topic  # topics carry no run id
            if channel.topic == "/ingest":
                counts["credits in ingest"] += len(json.loads(message.data).get("credits") or ())
            if schema.encoding == "jsonschema":
                if schema.id not in validators:
                    body = json.loads(schema.data)
                    jsonschema.Draft202012Validator.check_schema(body)
                    validators[schema.id] = jsonschema.Draft202012Validator(body)
                if channel.message_encoding == "json":
                    doc = json.loads(message.data)
                else:  # safetensors: the schema is that of its JSON header
                    assert channel.message_encoding == "safetensors"
                    (n,) = struct.unpack("<Q", message.data[:8])
                    doc = json.loads(message.data[8 : 8 + n])
                validators[schema.id].validate(doc)
            else:
                assert (schema.encoding, channel.message_encoding) == ("protobuf", "protobuf"), schema.name
                if schema.id not in classes:
                    classes[schema.id] = _protobuf_class(schema)
                parsed = classes[schema.id]()
                parsed.ParseFromString(message.data)
                assert parsed.SerializeToString(deterministic=True)  # something real, re-encodable
    # What a person needs to see the agent: the layout once per episode, the agent at every step, feedback marks.
    episodes, steps = counts["/episode"], counts["/step"]
    assert episodes == 6 and steps > 0
    assert counts["/scene/layout"] == episodes and counts["/scene/agent"] == steps
    assert counts["/scene/feedback"] == counts["/credit/oracle"] > 0
    # the oracle (the run's own teacher) had its Credits ride in Ingest; the recorder logged each on its own topic
    assert counts["credits in ingest"] == counts["/credit/oracle"]
    assert counts["/snapshot"] >= 2 and "/weights" not in counts  # bounded-rate weights, not every version

    # Foxglove's published schema (not the SDK that wrote the log): same types, and its classes parse the bytes.
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    scene_schema = next(s for s in summary.schemas.values() if s.name == "foxglove.SceneUpdate")
    ours = _protobuf_class(scene_schema).DESCRIPTOR
    _same_as_published(ours, SceneUpdate.DESCRIPTOR)
    with open(maze_log, "rb") as f:
        scenes = [
            (c.topic, m.data)
            for _, c, m in make_reader(f).iter_messages(topics=["/scene/layout", "/scene/agent", "/scene/feedback"])
        ]
    walls_seen = False
    for topic, data in scenes:
        msg = SceneUpdate()
        msg.ParseFromString(data)
        assert len(msg.entities) == 1 and msg.entities[0].frame_id == "env"
        if topic == "/scene/layout":
            walls_seen |= len(msg.entities[0].cubes) > 3  # floor, goal, start and the maze's walls
        if topic == "/scene/feedback":
            meta = {kv.key: kv.value for kv in msg.entities[0].metadata}
            assert meta["status"] in ("credited", "stale", "ignored", "after_end", "actor_restarted")
            if meta["status"] == "credited":
                weights = [float(x.split(":")[1]) for x in meta["steps"].split()]
                assert weights and abs(sum(weights) + float(meta["lost_mass"]) - 1.0) < 1e-3
    assert walls_seen


def test_run_id_is_in_the_metadata(maze_log):
    with open(maze_log, "rb") as f:
        meta = {m.name: m.metadata for m in make_reader(f).iter_metadata()}
    assert meta["hitl.run"]["run"] == "indep"
