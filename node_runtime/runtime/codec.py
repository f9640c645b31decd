"""msgpack encoding of everything that crosses the bus (documented in docs/bus.md).

Every payload is a map with ``v`` (schema version) and ``type``. Model envelopes inside a batch
are compact arrays: [kind, src, dst, seq, sent, arrive, body]. Decoding rebuilds the same
dataclasses the roles use, so a role cannot tell which transport delivered its mail.
"""

from __future__ import annotations

from typing import Any

import msgpack

from node_runtime.model.messages import Decision, Envelope, Kind, NodeState, Pending, Report, Result, Task
from node_runtime.model.view import Observation
from node_runtime.runtime.protocol import SCHEMA_VERSION, Batch, Done, Tick


class CodecError(ValueError):
    pass


# ----- model bodies -----

def _task(t: Task) -> list:
    return [t.id, t.origin, t.created, t.instructions, t.input_bytes, t.output_bytes, t.cpi, t.deadline,
            t.hops, list(t.path)]


def _untask(a: list) -> Task:
    return Task(a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7], a[8], tuple(a[9]))


def _body(kind: Kind, body: Any) -> Any:
    if kind == Kind.TASK:
        return _task(body)
    if kind == Kind.RESULT:
        return [_task(body.task), body.executor, body.finished, body.hop]
    if kind == Kind.DECISION:
        return [[d.task_id, d.target] for d in body]
    if kind == Kind.REPORT:
        return [[[p.id, p.origin, p.created, p.instructions, p.input_bytes, p.output_bytes, p.cpi, p.deadline,
                  p.arrived] for p in body.pending], body.busy_until]
    if kind == Kind.STATE:
        return [body.node, body.queue, body.occupancy]
    raise CodecError(f"no encoding for message kind {kind!r}")


def _unbody(kind: Kind, a: Any) -> Any:
    if kind == Kind.TASK:
        return _untask(a)
    if kind == Kind.RESULT:
        return Result(_untask(a[0]), a[1], a[2], a[3])
    if kind == Kind.DECISION:
        return [Decision(i, target) for i, target in a]
    if kind == Kind.REPORT:
        return Report([Pending(*p) for p in a[0]], a[1])
    if kind == Kind.STATE:
        return NodeState(a[0], a[1], a[2])
    raise CodecError(f"no decoding for message kind {kind!r}")


def _envelope(e: Envelope) -> list:
    return [int(e.kind), e.src, e.dst, e.seq, e.sent, e.arrive, _body(e.kind, e.body)]


def _unenvelope(a: list) -> Envelope:
    kind = Kind(a[0])
    return Envelope(kind, a[1], a[2], a[3], a[4], a[5], _unbody(kind, a[6]))


# ----- protocol messages -----

def to_wire(msg: Any) -> dict[str, Any]:
    if isinstance(msg, Batch):
        return {"type": "batch", "e": msg.episode, "t": msg.tick, "src": msg.src,
                "msgs": [_envelope(e) for e in msg.envelopes]}
    if isinstance(msg, Tick):
        return {"type": "tick", "e": msg.episode, "t": msg.tick, "cmd": msg.command, "expect": msg.expect,
                "actions": msg.actions, "seed": msg.seed, "external": msg.external, "policy": msg.policy}
    if isinstance(msg, Done):
        return {"type": "done", "proc": msg.proc, "e": msg.episode, "t": msg.tick, "sent": msg.sent,
                "stats": msg.stats, "rt": msg.response_times, "fl": msg.flights, "wake": msg.wake,
                "obs": {k: o.to_wire() for k, o in msg.obs.items()}, "error": msg.error}
    if isinstance(msg, dict):
        if "type" not in msg:
            raise CodecError("a plain message needs a 'type' field")
        return msg
    raise CodecError(f"cannot encode {type(msg).__name__}")


def from_wire(d: dict[str, Any]) -> Any:
    kind = d.get("type")
    if kind == "batch":
        return Batch(d["e"], d["t"], d["src"], [_unenvelope(a) for a in d["msgs"]])
    if kind == "tick":
        return Tick(d["e"], d["t"], d["cmd"], d["expect"], d["actions"], d["seed"], d["external"], d["policy"])
    if kind == "done":
        return Done(d["proc"], d["e"], d["t"], d["sent"], d["stats"], d["rt"], d["fl"], d["wake"],
                    {k: Observation.from_wire(o) for k, o in d["obs"].items()}, d["error"])
    return d


def encode(msg: Any) -> bytes:
    d = to_wire(msg)
    d["v"] = SCHEMA_VERSION
    return msgpack.packb(d, use_bin_type=True)


def decode(data: bytes) -> Any:
    d = msgpack.unpackb(data, raw=False, strict_map_key=False)
    if not isinstance(d, dict) or d.get("v") != SCHEMA_VERSION:
        raise CodecError(f"unsupported payload (schema {d.get('v') if isinstance(d, dict) else '?'}, "
                         f"expected {SCHEMA_VERSION})")
    return from_wire(d)
