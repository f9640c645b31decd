"""msgpack encoding of everything that crosses the bus (documented in docs/bus.md).

Every payload is a map with ``v`` (schema version) and ``type``. Model envelopes inside a batch
are compact arrays: [kind, src, dst, seq, sent, arrive, body]. Decoding rebuilds the same
dataclasses the roles use, so a role cannot tell which transport delivered its mail.

Anyone who reaches the router can publish, so decoding checks the shape of every protocol message
(fields present, of the right types, arrays of the right length) and raises ``CodecError`` with the
reason for anything else: handlers only ever see well-formed messages. Whether a well-formed
message may be trusted (its sender, its tick) is for the handlers to decide.

A tick, done or dones may be sealed (``encode(msg, seal=key)``): a ``mac`` field, last, holds the keyed
BLAKE2b of every byte before it (``origin``). ``decode`` hands the message over with ``mac`` and ``signed``
(those bytes) set, for the handlers to check against the key of the sender the message names.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, NoReturn

import msgpack

from node_runtime.model.messages import (
    Decision,
    Envelope,
    JobRef,
    Kind,
    NodeState,
    Pending,
    Report,
    Result,
    Task,
    TaskSize,
)
from node_runtime.model.role import STAT_FIELDS
from node_runtime.model.view import Observation
from node_runtime.runtime.origin import MAC_BYTES, mac
from node_runtime.runtime.protocol import SCHEMA_VERSION, Batch, Done, Dones, Tick
from node_runtime.runtime.rejections import BAD_MSGPACK, TOO_LARGE, WRONG_SHAPE
from node_runtime.runtime.rejections import SCHEMA_VERSION as OTHER_SCHEMA


class CodecError(ValueError):
    """A payload that cannot be encoded, or decoded into a well-formed message; ``reason`` says why
    in the vocabulary of ``rejections``."""

    def __init__(self, message: str, reason: str = WRONG_SHAPE) -> None:
        super().__init__(message)
        self.reason = reason


def _malformed(what: str) -> NoReturn:
    raise CodecError(what)


# ----- shapes: what each array and map may hold (bool passes for int, as in Python) -----

NUM = (int, float)
TASK = (int, str, int, NUM, NUM, NUM, NUM, NUM, int, list, object, object)
RESULT = (list, str, int, int, NUM)
DECISION = (int, str)
PENDING = (int, str, int, NUM, NUM, NUM, NUM, NUM, int, object)
STATE = (str, int, int, NUM)
ENVELOPE = (int, str, str, int, int, int, object)
NODE_VIEW = (str, NUM, NUM, NUM, NUM, NUM, NUM, NUM, bool, NUM, NUM)
TASK_VIEW = (int, NUM, NUM, NUM, NUM, NUM, NUM, NUM, str, object)
JOB_REF = (int, int, NUM, NUM)
OBSERVATION = (int, str, list, int, list, list, list)
N_STATS = len(STAT_FIELDS)


def _fits(a: Any, shape: tuple) -> bool:
    """An array of exactly these element types."""
    return type(a) is list and len(a) == len(shape) and all(map(isinstance, a, shape))


_is_int = int.__instancecheck__  # isinstance(x, int) without a Python frame: these run for every message
_is_str = str.__instancecheck__


def _number_rows(rows: Any, length: int | None = None) -> bool:
    """Lists of numbers, of ``length`` each if given. Of what msgpack decodes, ``sum`` refuses anything
    but numbers (bool counts as one), and does it in C."""
    if not all(map(list.__instancecheck__, rows)):
        return False
    if length is not None and not all(map(length.__eq__, map(len, rows))):
        return False
    try:
        sum(map(sum, rows))
    except TypeError:
        return False
    return True


def _int_map(m: Any) -> bool:
    """A map int -> int (process or role index -> count, tick -> count)."""
    return type(m) is dict and (not m or (all(map(_is_int, m)) and all(map(_is_int, m.values()))))


def _stats(m: Any) -> bool:
    return type(m) is dict and (not m or (all(map(_is_int, m)) and _number_rows(m.values(), N_STATS)))


def _drift(m: Any) -> bool:
    """Role index -> what each tick adds to its stats: finite, and nothing is ever taken away."""
    return _stats(m) and all(0.0 <= x < math.inf for row in m.values() for x in row)


def _held(m: Any) -> bool:
    """Process index -> [publications held for it (at least one, or it would not be named), tick or nil]."""
    return type(m) is dict and (not m or (all(map(_is_int, m)) and all(
        type(v) is list and len(v) == 2 and _is_int(v[0]) and v[0] > 0 and (v[1] is None or _is_int(v[1]))
        for v in m.values())))


def _is_state(queue: Any, occupancy: Any, drains_at: Any) -> bool:
    """A worker's state as broadcast: counts, and a drain tick that observations turn into seconds of work."""
    return (_is_int(queue) and _is_int(occupancy) and 0 <= queue <= occupancy and isinstance(drains_at, NUM)
            and 0.0 <= drains_at < math.inf)


def _states_of(n: int) -> Callable[[Any], bool]:
    """Role index -> [queue, occupancy, drains_at (``_is_state``), then n non-negative ints]."""
    def ok(m: Any) -> bool:
        return type(m) is dict and (not m or (all(map(_is_int, m)) and all(
            type(v) is list and len(v) == 3 + n and _is_state(*v[:3]) and all(map(_is_int, v[3:])) and min(v[3:]) >= 0
            for v in m.values())))
    return ok


_states = _states_of(1)  # Done: worker role index -> [queue, occupancy, drains_at, seq]
_tick_states = _states_of(2)  # Tick: worker role index -> [queue, occupancy, drains_at, tick sent, seq]


def _report(v: Any) -> bool:
    """[arrival tick, tasks pending (>= 0), links' busy-until ticks (finite numbers >= 0) or nil]."""
    return (type(v) is list and len(v) == 3 and _is_int(v[0]) and _is_int(v[1]) and v[1] >= 0
            and (v[2] is None or (_number_rows([v[2]]) and all(0.0 <= x < math.inf for x in v[2]))))


def _reports(m: Any) -> bool:
    return type(m) is dict and (not m or (all(map(_is_int, m)) and all(map(_report, m.values()))))


def _times(m: Any) -> bool:
    return type(m) is dict and (not m or (all(map(_is_int, m)) and _number_rows(m.values())))


LEDGER_KINDS = range(3)  # role.COMPLETED, LOST, CHARGED


def _ledger_entry(a: Any) -> bool:
    """[task id, kind, value]: a value feeds rewards, so it is finite and not negative."""
    return (type(a) is list and len(a) == 3 and _is_int(a[0]) and _is_int(a[1]) and a[1] in LEDGER_KINDS
            and isinstance(a[2], NUM) and 0.0 <= a[2] < math.inf)


def _ledger(m: Any) -> bool:
    return type(m) is dict and (not m or (all(map(_is_int, m)) and all(
        type(v) is list and all(map(_ledger_entry, v)) for v in m.values())))


def _flights(m: Any) -> bool:
    return type(m) is dict and (not m or (all(map(_is_int, m)) and all(map(_int_map, m.values()))))


def _observations(m: Any) -> bool:
    return type(m) is dict and (not m or (all(map(_is_int, m)) and all(
        _fits(o, OBSERVATION) and _fits(o[2], NODE_VIEW) and all(_fits(t, TASK_VIEW) and _is_job(t[9]) for t in o[4])
        and all(_fits(n, NODE_VIEW) for n in o[5]) and _number_rows([o[6]]) for o in m.values())))


def _actions(m: Any) -> bool:
    """Controller role -> an int, or a list of ints in batch mode."""
    return type(m) is dict and (not m or (all(map(_is_str, m)) and all(
        isinstance(a, int) or (type(a) is list and all(map(_is_int, a))) for a in m.values())))


def _str_list(a: Any) -> bool:
    return type(a) is list and all(map(_is_str, a))


def _counts(m: Any) -> bool:
    """Reason -> count."""
    return type(m) is dict and (not m or (all(map(_is_str, m)) and all(map(_is_int, m.values()))))


def _maybe_int(x: Any) -> bool:
    return x is None or isinstance(x, int)


def _maybe_str(x: Any) -> bool:
    return x is None or isinstance(x, str)


COMMANDS = ("run", "reset", "stop", "fence")
TICK_FIELDS = (("ep", _is_int), ("e", _is_int), ("t", _is_int), ("cmd", COMMANDS.__contains__),
               ("expect", _int_map), ("actions", _actions), ("seed", _is_int), ("external", _str_list),
               ("policy", _maybe_str), ("st", _tick_states))
DONE_FIELDS = (("proc", _is_str), ("ep", _is_int), ("e", _is_int), ("t", _is_int), ("sent", _int_map),
               ("stats", _stats), ("rt", _times), ("fl", _flights), ("wake", _maybe_int), ("obs", _observations),
               ("error", _maybe_str), ("led", _ledger), ("dr", _drift), ("hd", _held), ("st", _states),
               ("rp", _reports))
# "rej" (optional) comes last: a done that passes every field above is malformed there
BATCH_FIELDS = (("e", _is_int), ("t", _is_int), ("src", _is_str), ("msgs", list.__instancecheck__))


def _diagnose(d: dict[str, Any], kind: str, fields: tuple) -> NoReturn:
    """Name the first field of a malformed message that is not of its documented shape (docs/bus.md)."""
    for name, ok in fields:
        if not ok(d[name]):
            _malformed(f"{kind} field {name!r} is not of the documented shape")
    _malformed(f"{kind} field 'rej' is not of the documented shape")


# ----- model bodies -----

def _job(j: JobRef | None) -> list | None:
    return None if j is None else list(j)


def _is_job(a: Any) -> bool:
    """nil (a task on its own), or [job id, index, critical cycles, successor bytes]."""
    return a is None or _fits(a, JOB_REF)


def _unjob(a: Any) -> JobRef | None:
    return None if a is None else JobRef(*a)


def _task(t: Task) -> list:
    return [t.id, t.origin, t.created, *t.size, t.hops, list(t.path), _job(t.job), t.type]


def _untask(a: Any) -> Task:
    if not (_fits(a, TASK) and _str_list(a[9]) and _is_job(a[10]) and _maybe_int(a[11])):
        _malformed("a task that is not [id, origin, created, instructions, input, output, cpi, deadline, hops, path, "
                   "job, type]")
    return Task(a[0], a[1], a[2], TaskSize(a[3], a[4], a[5], a[6], a[7]), a[8], tuple(a[9]), _unjob(a[10]), a[11])


def _body(kind: Kind, body: Any) -> Any:
    if kind == Kind.TASK:
        return _task(body)
    if kind == Kind.RESULT:
        return [_task(body.task), body.executor, body.finished, body.hop, body.imposed]
    if kind == Kind.DECISION:
        return [[d.task_id, d.target] for d in body]
    if kind == Kind.REPORT:
        return [[[p.id, p.origin, p.created, *p.size, p.arrived, _job(p.job)] for p in body.pending], body.busy_until]
    if kind == Kind.STATE:
        return [body.node, body.queue, body.occupancy, body.drains_at]
    raise CodecError(f"no encoding for message kind {kind!r}")


def _unbody(kind: Kind, a: Any) -> Any:
    if kind == Kind.TASK:
        return _untask(a)
    if kind == Kind.RESULT:
        if not (_fits(a, RESULT) and 0.0 <= a[4] < math.inf):  # imposed feeds rewards: no nan, no negatives
            _malformed("a result that is not [task, executor, finished, hop, imposed >= 0]")
        return Result(_untask(a[0]), a[1], a[2], a[3], a[4])
    if kind == Kind.DECISION:
        if not (type(a) is list and all(_fits(d, DECISION) for d in a)):
            _malformed("decisions that are not [[task id, target], ...]")
        return [Decision(i, target) for i, target in a]
    if kind == Kind.REPORT:
        if not (type(a) is list and len(a) == 2 and type(a[0]) is list
                and all(_fits(p, PENDING) and _is_job(p[9]) for p in a[0])
                and (a[1] is None or (type(a[1]) is list and all(isinstance(x, NUM) for x in a[1])))):
            _malformed("a report that is not [[pending task, ...], link busy-until ticks or nil]")
        return Report([Pending(p[0], p[1], p[2], TaskSize(*p[3:8]), p[8], _unjob(p[9])) for p in a[0]], a[1])
    if not (_fits(a, STATE) and _is_state(*a[1:])):  # Kind.STATE: the kinds are exhausted
        _malformed("a state that is not [node, queue <= occupancy, drains_at >= 0]")
    return NodeState(a[0], a[1], a[2], a[3])


def _envelope(e: Envelope) -> list:
    return [int(e.kind), e.src, e.dst, e.seq, e.sent, e.arrive, _body(e.kind, e.body)]


KINDS = {int(k): k for k in Kind}


def _unenvelope(a: Any) -> Envelope:
    if not _fits(a, ENVELOPE) or a[0] not in KINDS:
        _malformed("an envelope that is not [kind 1-5, src, dst, seq, sent, arrive, body]")
    kind = KINDS[a[0]]
    return Envelope(kind, a[1], a[2], a[3], a[4], a[5], _unbody(kind, a[6]))


# ----- protocol messages -----

def to_wire(msg: Any) -> dict[str, Any]:
    if isinstance(msg, Batch):
        return {"type": "batch", "e": msg.episode, "t": msg.tick, "src": msg.src,
                "msgs": [_envelope(e) for e in msg.envelopes]}
    if isinstance(msg, Tick):
        return {"type": "tick", "ep": msg.epoch, "e": msg.episode, "t": msg.tick, "cmd": msg.command,
                "expect": msg.expect, "actions": msg.actions, "seed": msg.seed, "external": msg.external,
                "policy": msg.policy, "st": msg.states}
    if isinstance(msg, Done):
        return _done_wire(msg)
    if isinstance(msg, Dones):
        return {"type": "dones", "group": msg.group, "ep": msg.epoch, "dones": [_done_wire(d) for d in msg.dones]}
    if isinstance(msg, dict):
        if "type" not in msg:
            raise CodecError("a plain message needs a 'type' field")
        return msg
    raise CodecError(f"cannot encode {type(msg).__name__}")


def _done_wire(msg: Done) -> dict[str, Any]:
    d = {"type": "done", "proc": msg.proc, "ep": msg.epoch, "e": msg.episode, "t": msg.tick, "sent": msg.sent,
         "stats": msg.stats, "rt": msg.response_times, "fl": msg.flights, "wake": msg.wake,
         "obs": {k: o.to_wire() for k, o in msg.obs.items()}, "error": msg.error, "led": msg.ledger,
         "dr": msg.drift, "hd": msg.held, "st": msg.states, "rp": msg.reports}
    if msg.rejected:
        d["rej"] = msg.rejected
    return d


def from_wire(d: dict[str, Any]) -> Any:
    """The protocol message a map stands for (its shape checked), or the map itself for other types."""
    kind = d.get("type")
    try:
        if kind == "done":
            return _done(d)
        if kind == "batch":
            return _batch(d)
        if kind == "tick":
            return _tick(d)
        if kind == "dones":
            return _dones(d)
    except KeyError as exc:
        raise CodecError(f"{kind} without field {exc}") from None
    return d


# Each reader tests every field in one expression (the common case: a well-formed message, mostly
# empty maps), and only when that fails walks the fields one by one to say which is wrong.
EMPTY: dict = {}  # compared with ==, so only an empty map matches; never mutated
NONE: list = []


def _done(d: dict[str, Any]) -> Done:
    proc, ep, e, t, sent, stats = d["proc"], d["ep"], d["e"], d["t"], d["sent"], d["stats"]
    rt, fl = d["rt"], d["fl"]
    wake, obs, error, ledger, drift, held, states = d["wake"], d["obs"], d["error"], d["led"], d["dr"], d["hd"], d["st"]
    reports = d["rp"]
    rejected = d.get("rej", EMPTY)
    if not (isinstance(proc, str) and isinstance(ep, int) and isinstance(e, int) and isinstance(t, int)
            and (wake is None or isinstance(wake, int)) and (error is None or isinstance(error, str))
            and (sent == EMPTY or _int_map(sent))
            and (stats == EMPTY or _stats(stats)) and (rt == EMPTY or _times(rt)) and (fl == EMPTY or _flights(fl))
            and (obs == EMPTY or _observations(obs)) and (ledger == EMPTY or _ledger(ledger))
            and (drift == EMPTY or _drift(drift)) and (held == EMPTY or _held(held))
            and (states == EMPTY or _states(states)) and (reports == EMPTY or _reports(reports))
            and (rejected is EMPTY or _counts(rejected))):
        _diagnose(d, "done", DONE_FIELDS)
    return Done(proc, e, t, sent, stats, rt, fl, wake, {k: Observation.from_wire(o) for k, o in obs.items()},
                error, rejected, {k: [tuple(x) for x in v] for k, v in ledger.items()}, drift,
                {k: tuple(v) for k, v in held.items()},
                {k: tuple(v) for k, v in states.items()}, {k: tuple(v) for k, v in reports.items()}, ep)


def _dones(d: dict[str, Any]) -> Dones:
    group, ep, dones = d["group"], d["ep"], d["dones"]
    if not isinstance(group, str):
        _malformed("dones field 'group' is not of the documented shape")
    if not isinstance(ep, int):
        _malformed("dones field 'ep' is not of the documented shape")
    if not (type(dones) is list and all(type(x) is dict and x.get("type") == "done" for x in dones)):
        _malformed("dones field 'dones' is not a list of done maps")
    return Dones(group, [_done(x) for x in dones], ep)


def _batch(d: dict[str, Any]) -> Batch:
    e, t, src, msgs = d["e"], d["t"], d["src"], d["msgs"]
    if not (isinstance(e, int) and isinstance(t, int) and isinstance(src, str) and type(msgs) is list):
        _diagnose(d, "batch", BATCH_FIELDS)
    return Batch(e, t, src, [_unenvelope(a) for a in msgs])


def _tick(d: dict[str, Any]) -> Tick:
    ep, e, t, cmd, expect, actions = d["ep"], d["e"], d["t"], d["cmd"], d["expect"], d["actions"]
    seed, external, policy, states = d["seed"], d["external"], d["policy"], d["st"]
    if not (isinstance(ep, int) and isinstance(e, int) and isinstance(t, int) and cmd in COMMANDS
            and (expect == EMPTY or _int_map(expect))
            and (actions == EMPTY or _actions(actions)) and isinstance(seed, int)
            and (external == NONE or _str_list(external)) and (policy is None or isinstance(policy, str))
            and (states == EMPTY or _tick_states(states))):
        _diagnose(d, "tick", TICK_FIELDS)
    return Tick(e, t, cmd, expect, actions, seed, external, policy,
                {k: tuple(v) for k, v in states.items()} if states else {}, ep)


SEALED = (Tick, Done, Dones)
NO_MAC = bytes(MAC_BYTES)


def encode(msg: Any, seal: bytes | None = None) -> bytes:
    """``seal``: the sender's key; the MAC goes last, over every byte before it."""
    d = to_wire(msg)
    d["v"] = SCHEMA_VERSION
    if seal is None:
        return msgpack.packb(d, use_bin_type=True)
    d["mac"] = NO_MAC
    signed = msgpack.packb(d, use_bin_type=True)[:-MAC_BYTES]
    return signed + mac(seal, signed)


def check_size(size: int, limit: int) -> None:
    """Refuse a payload larger than ``limit`` bytes (limits.py) before it is copied or decoded."""
    if size > limit:
        raise CodecError(f"{size} bytes, more than the {limit} a message on this key may have", TOO_LARGE)


def decode(data: bytes, limit: int | None = None) -> Any:
    """Bytes from the bus -> a message; ``CodecError`` (and nothing else) for anything that is not one.
    ``limit``: the most bytes the payload may have (limits.py); msgpack itself bounds every string, array
    and map by the payload's length."""
    if limit is not None:
        check_size(len(data), limit)
    try:
        d = msgpack.unpackb(data, raw=False, strict_map_key=False)
    except Exception as exc:  # msgpack raises ValueError, TypeError, StackError, UnicodeDecodeError, ...
        raise CodecError(f"not msgpack: {type(exc).__name__}{f': {exc}' if str(exc) else ''}", BAD_MSGPACK) from None
    if type(d) is not dict:
        _malformed(f"a msgpack {type(d).__name__}, not a map")
    if d.get("v") != SCHEMA_VERSION:
        raise CodecError(f"schema version {d.get('v')!r}, expected {SCHEMA_VERSION}: every host needs the same "
                         "ZenohEdge version", OTHER_SCHEMA)
    msg = from_wire(d)
    if type(msg) in SEALED:
        tag = d.get("mac")
        if type(tag) is bytes and len(tag) == MAC_BYTES and data.endswith(tag):  # else ``mac`` stays None
            msg.mac = tag
            msg.signed = data[:-MAC_BYTES]
    return msg
