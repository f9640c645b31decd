"""Whatever reaches a decoder, it raises nothing but ``CodecError``, and what it accepts is well formed.

Anyone who reaches the router can publish, so these feed the codec arbitrary bytes, arbitrary msgpack
values, maps shaped like protocol messages with arbitrary fields, and real messages with one part
replaced by anything.
"""

from __future__ import annotations

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from node_runtime.model.messages import Decision, Envelope, Kind, NodeState, Pending, Report, Result, Task, TaskSize
from node_runtime.model.role import STAT_FIELDS
from node_runtime.model.view import NodeView, Observation, TaskView
from node_runtime.runtime import codec
from node_runtime.runtime.protocol import SCHEMA_VERSION, Batch, Done, Dones, Tick
from node_runtime.runtime.rejections import BAD_MSGPACK, WRONG_SHAPE
from node_runtime.runtime.rejections import SCHEMA_VERSION as OTHER_SCHEMA

FUZZ = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])

TASK = Task((3 << 32) | 9, "rpi3_0", 12, TaskSize(8e7, 1.5e8, 1.5e8, 1.0, 100.0), 1, ("rpi3_0", "nuc_0"))
OBS = Observation(5, "a", NodeView("a", 1, 2, 3, 4e6, 0, 0.0, 1, True), 2,
                  [TaskView(7, TaskSize(8e7, 1.0, 2.0, 1.0, 100.0), 95.0, 2, "a")],
                  [NodeView("b", 0, 0, 26, 4e6, 1, 3e7, 1, True, 2.5)])
GOOD = [
    Tick(2, 17, "run", {0: 2}, {"controller:a": 1, "controller:b": [0, 2]}),
    Tick(3, 0, "reset", seed=9, external=["controller:a"], policy="least_queue"),
    Done("node-a", 2, 17, {1: 1}, {0: [1] * len(STAT_FIELDS)}, {1: [7.0]}, {0: {19: 2}}, 18, {2: OBS},
         rejected={"bad_msgpack": 2}, ledger={1: [(TASK.id, 0, 7.0), (12, 2, 0.5)], 0: [(13, 1, 0.0)]}),
    Done("node-a", 2, 17, {}, {}, error="ValueError: boom"),
    Dones("host-1", [Done("node-a", 2, 17, {1: 1}, {}, wake=18), Done("node-b", 2, 17, {}, {}, error="boom")]),
    Batch(0, 5, "node-a", [
        Envelope(Kind.TASK, "worker:a", "worker:b", 1, 4, 7, TASK),
        Envelope(Kind.RESULT, "worker:b", "client:a", 2, 5, 6, Result(TASK, "b", 5, 1)),
        Envelope(Kind.DECISION, "controller:a", "worker:a", 3, 5, 6, [Decision(1, ""), Decision(2, "b")]),
        Envelope(Kind.REPORT, "worker:a", "controller:a", 4, 5, 6, Report([Pending.of(TASK, 3)], [7.5, 0.0])),
        Envelope(Kind.STATE, "worker:a", "state/a", 5, 5, 6, NodeState("a", 2, 3, 4.5)),
    ]),
]
PROTOCOL_FIELDS = sorted({k for m in GOOD for k in codec.to_wire(m)} - {"type"})

scalars = (st.none() | st.booleans() | st.integers(min_value=-(2**63), max_value=2**64 - 1) | st.floats()
           | st.text(max_size=8) | st.binary(max_size=8))
values = st.recursive(scalars, lambda inner: st.lists(inner, max_size=4)
                      | st.dictionaries(st.integers(-3, 40) | st.text(max_size=4), inner, max_size=4), max_leaves=20)


def decoded(data: bytes):
    """What the codec makes of ``data``: a message, or the CodecError it raised (nothing else may escape)."""
    try:
        return codec.decode(data)
    except codec.CodecError as exc:
        assert exc.reason in (BAD_MSGPACK, OTHER_SCHEMA, WRONG_SHAPE)
        return exc


def assert_well_formed(msg) -> None:
    """A decoded protocol message survives another trip through the codec unchanged."""
    if isinstance(msg, Tick | Done | Dones | Batch):
        assert codec.decode(codec.encode(msg)) == msg


@FUZZ
@given(st.binary(max_size=200))
def test_arbitrary_bytes(data):
    assert_well_formed(decoded(data))


@FUZZ
@given(values)
def test_arbitrary_msgpack(value):
    assert_well_formed(decoded(msgpack.packb(value, use_bin_type=True)))


@FUZZ
@given(st.sampled_from(["tick", "done", "batch", "metrics", 7]), st.sampled_from([SCHEMA_VERSION, 1, 3, None, "2"]),
       st.dictionaries(st.sampled_from(PROTOCOL_FIELDS), values, max_size=len(PROTOCOL_FIELDS)))
def test_protocol_shaped_maps(kind, version, fields):
    msg = decoded(msgpack.packb({**fields, "type": kind, "v": version}, use_bin_type=True))
    assert_well_formed(msg)
    if version != SCHEMA_VERSION:
        assert isinstance(msg, codec.CodecError) and msg.reason == OTHER_SCHEMA


def paths(node, prefix=()):
    """Every place inside a decoded wire structure, as a path of keys and indices."""
    yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from paths(v, (*prefix, i))


@FUZZ
@given(st.sampled_from(GOOD), st.data(), values)
def test_real_messages_with_one_part_replaced(message, data, replacement):
    wire = msgpack.unpackb(codec.encode(message), raw=False, strict_map_key=False)
    where = data.draw(st.sampled_from([p for p in paths(wire) if p]))
    node = wire
    for step in where[:-1]:
        node = node[step]
    node[where[-1]] = replacement
    assert_well_formed(decoded(msgpack.packb(wire, use_bin_type=True)))


@pytest.mark.parametrize("message", GOOD, ids=lambda m: type(m).__name__)
def test_every_field_is_required(message):
    wire = codec.to_wire(message)
    for name in set(wire) - {"type", "rej"}:
        data = msgpack.packb({**{k: v for k, v in wire.items() if k != name}, "v": SCHEMA_VERSION})
        with pytest.raises(codec.CodecError, match=repr(name)):
            codec.decode(data)


def test_reasons_name_what_is_wrong():
    with pytest.raises(codec.CodecError, match="not msgpack") as exc:
        codec.decode(b"\xc1")
    assert exc.value.reason == BAD_MSGPACK
    with pytest.raises(codec.CodecError, match=f"schema version 2, expected {SCHEMA_VERSION}") as exc:
        codec.decode(msgpack.packb({**codec.to_wire(GOOD[0]), "v": 2}))
    assert exc.value.reason == OTHER_SCHEMA
    with pytest.raises(codec.CodecError, match="done field 'stats'") as exc:
        codec.decode(codec.encode(Done("p", 0, 1, {}, {0: [1, 2, 3]})))
    assert exc.value.reason == WRONG_SHAPE
    with pytest.raises(codec.CodecError, match="envelope"):
        bad = codec.to_wire(GOOD[-1]) | {"v": SCHEMA_VERSION}  # the batch
        bad["msgs"][0][0] = 9  # no such kind
        codec.decode(msgpack.packb(bad))
