"""Everything that crosses the bus decodes to what was encoded."""

from __future__ import annotations

import msgpack
import pytest

from node_runtime.model.messages import Decision, Envelope, Kind, NodeState, Pending, Report, Result, Task, TaskSize
from node_runtime.model.view import NodeView, Observation, TaskView
from node_runtime.runtime import codec
from node_runtime.runtime.codec import N_STATS
from node_runtime.runtime.protocol import SCHEMA_VERSION, Batch, Done, Tick


def task(**kw):
    base = dict(id=(3 << 32) | 9, origin="rpi3_0", created=12, size=TaskSize(8e7, 157286400.0, 1.5e8, 1.0, 100.0),
                hops=1, path=("rpi3_0", "nuc_0"))
    base.update(kw)
    return Task(**base)


def test_batch_roundtrip():
    envs = [
        Envelope(Kind.TASK, "worker:a", "worker:b", 1, 4, 7, task()),
        Envelope(Kind.TASK, "worker:a", "worker:b", 1, 4, 7, task(type=2)),
        Envelope(Kind.RESULT, "worker:b", "client:a", 2, 5, 6, Result(task(), "b", 5, 1, 12.5)),
        Envelope(Kind.DECISION, "controller:a", "worker:a", 3, 5, 6, [Decision(1, ""), Decision(2, "b")]),
        Envelope(Kind.REPORT, "worker:a", "controller:a", 4, 5, 6,
                 Report([Pending(1, "a", 2, TaskSize(1e6, 1.0, 2.0, 1.0, 9.0), 3)], [7.5, 0.0])),
        Envelope(Kind.STATE, "worker:a", "state/a", 5, 5, 6, NodeState("a", 2, 3, 9.25)),
    ]
    msg = Batch(0, 5, "node-a", envs)
    assert codec.decode(codec.encode(msg)) == msg


@pytest.mark.parametrize("state", [[2, 3, -1.0], [2, 3, float("nan")], [2, 3, float("inf")], [2, 3, "9"],
                                   [4, 3, 9.0], [2.0, 3, 9.0], [-1, 3, 9.0], [2, 3]])
def test_a_state_is_counts_and_a_finite_drain_tick(state):
    """A state feeds every neighbour's observation: a forged count or drain tick must not reach them."""
    wire = codec.to_wire(Batch(0, 5, "node-a", [Envelope(Kind.STATE, "worker:a", "state/a", 5, 5, 6,
                                                         NodeState("a", 2, 3, 9.0))]))
    wire["msgs"][0][6][1:] = state
    with pytest.raises(codec.CodecError, match="drains_at >= 0"):
        codec.decode(msgpack.packb({**wire, "v": SCHEMA_VERSION}))


@pytest.mark.parametrize("imposed", [-1.0, float("nan"), float("inf"), "3"])
def test_a_result_must_impose_a_finite_delay_of_at_least_zero(imposed):
    """The delay a result reports feeds the agents' rewards: a forged one must not reach them."""
    wire = codec.to_wire(Batch(0, 5, "node-b", [Envelope(Kind.RESULT, "worker:b", "client:a", 2, 5, 6,
                                                         Result(task(), "b", 5, 1, 1.0))]))
    wire["msgs"][0][6][4] = imposed
    with pytest.raises(codec.CodecError, match="imposed >= 0"):
        codec.decode(msgpack.packb({**wire, "v": SCHEMA_VERSION}))


@pytest.mark.parametrize("kind", ["1", 1.5, [0]])
def test_a_task_type_is_an_index_or_nil(kind):
    """A task's type indexes the scenario's task types (the receiving process checks the range)."""
    wire = codec.to_wire(Batch(0, 5, "node-b", [Envelope(Kind.TASK, "worker:a", "worker:b", 1, 4, 7, task(type=0))]))
    wire["msgs"][0][6][11] = kind
    with pytest.raises(codec.CodecError, match=r"path, job, type\]"):
        codec.decode(msgpack.packb({**wire, "v": SCHEMA_VERSION}))


def test_tick_and_done_roundtrip():
    tick = Tick(2, 17, "run", {0: 2}, {"controller:a": 1, "controller:b": [0, 2]}, 0, [], None,
                {4: (2, 3, 19.5, 16, 9), 7: (0, 1, 0.0, 12, 3)})
    assert codec.decode(codec.encode(tick)) == tick
    obs = Observation(5, "a", NodeView("a", 1, 2, 3, 4e6, 0, 0.0, 1, True, 0.0, 7.5), 2,
                      [TaskView(7, TaskSize(8e7, 1.0, 2.0, 1.0, 100.0), 95.0, 2, "a")],
                      [NodeView("b", 0, 0, 26, 4e6, 1, 3e7, 1, True, 2.5)])
    stats = [1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 2.5, 0.0, 0.0, 0.0, 0.0, 1, 0, 0] + [0] * (N_STATS - 19)
    done = Done("node-a", 2, 17, {1: 1}, {0: stats}, {1: [7.0]}, {0: {19: 2, 21: 1}}, 18, {2: obs},
                ledger={1: [(7, 0, 7.0), (9, 2, 0.25)], 0: [(12, 1, 0.0)]},
                drift={0: [0.0] * 11 + [4e6] + [0.0] * (N_STATS - 12)},
                held={3: (1, None), 4: (2, 21)}, states={0: (2, 3, 18.5, 11)},
                reports={2: (18, 1, [19.0, 0.0]), 5: (18, 0, None)})
    assert codec.decode(codec.encode(done)) == done


@pytest.mark.parametrize(("field", "value"), [("hd", {3: [0, None]}), ("hd", {3: [-1, None]}), ("hd", {3: [1.0, 5]}),
                                              ("hd", {"3": [1, None]}), ("hd", {3: 1}), ("hd", {3: [1, 2.5]}),
                                              ("hd", {3: [1, None, 2]}),
                                              ("st", {0: [1, -1, 0.0, 2]}), ("st", {0: [1]}), ("st", {0: [1, 2, 3]}),
                                              ("st", {0: [1.5, 2, 0.0, 3]}), ("st", {"0": [1, 2, 0.0, 3]}),
                                              ("st", {0: [1, 2, -1.0, 3]}), ("st", {0: [1, 2, float("nan"), 3]}),
                                              ("st", {0: [1, 2, 0.0, 3, 4]}), ("st", {0: [3, 2, 0.0, 3]}),
                                              ("rp", {2: [18, -1, None]}), ("rp", {2: [18.0, 1, None]}),
                                              ("rp", {2: [18, 1, [-1.0]]}), ("rp", {2: [18, 1, [float("nan")]]}),
                                              ("rp", {2: [18, 1, ["1"]]}), ("rp", {2: [18, 1]}),
                                              ("rp", {"2": [18, 1, None]})])
def test_held_counts_states_and_reports_are_of_their_shape(field, value):
    """Held counts are added to a process's next tick, states and reports to the agents' observations: a
    forged negative, fractional, infinite or misshapen one must reach neither."""
    wire = codec.to_wire(Done("node-a", 2, 17, {}, {}, held={3: (1, 19)}, states={0: (2, 3, 6.5, 4)}))
    wire[field] = value
    with pytest.raises(codec.CodecError, match=f"field '{field}'"):
        codec.decode(msgpack.packb({**wire, "v": SCHEMA_VERSION}))


@pytest.mark.parametrize("value", [{4: [2, 3, 0.0, 16]}, {4: [2, -3, 0.0, 16, 9]}, {4: [2, 3, 0.0, 16.5, 9]},
                                   {"4": [2, 3, 0.0, 16, 9]}, {4: [2, 3, 0.0, 16, None]}, [[2, 3, 0.0, 16, 9]],
                                   {4: [2, 3, float("inf"), 16, 9]}, {4: [2, 3, None, 16, 9]}])
def test_states_with_a_tick_are_of_their_shape(value):
    """A tick hands a process the states it holds (``Tick.states``): a misshapen one never becomes its mail."""
    wire = codec.to_wire(Tick(2, 17, states={4: (2, 3, 17.5, 16, 9)}))
    wire["st"] = value
    with pytest.raises(codec.CodecError, match="field 'st'"):
        codec.decode(msgpack.packb({**wire, "v": SCHEMA_VERSION}))


@pytest.mark.parametrize("row", [[0.0] * (N_STATS - 1) + [-1.0], [0.0] * (N_STATS - 1) + [float("nan")],
                                 [0.0] * (N_STATS - 1) + [float("inf")], [0.0] * (N_STATS - 1),
                                 [0.0] * (N_STATS - 1) + ["1"]])
def test_a_drift_is_a_row_of_stats_that_only_ever_adds(row):
    """A drift moves a sleeping role's counters every tick: a forged one must not take from them or poison them."""
    wire = codec.to_wire(Done("node-a", 2, 17, {}, {0: [0] * N_STATS}, drift={0: [0.0] * N_STATS}))
    wire["dr"] = {0: row}
    with pytest.raises(codec.CodecError, match="field 'dr'"):
        codec.decode(msgpack.packb({**wire, "v": SCHEMA_VERSION}))


@pytest.mark.parametrize("entry", [[7, 3, 1.0], [7, -1, 0.0], [7, 1.0, 0.0], [7, 2, -0.5], [7, 2, float("nan")],
                                   [7, 2, float("inf")], [7, 2, "1"], ["7", 0, 1.0], [7, 0], [7, 0, 1.0, 2]])
def test_a_ledger_entry_is_a_task_a_known_kind_and_a_finite_value_of_at_least_zero(entry):
    """The ledger feeds the agents' credits: a forged entry must not reach them."""
    wire = codec.to_wire(Done("node-a", 2, 17, {}, {}, ledger={0: [(1, 0, 3.0)]}))
    wire["led"] = {0: [entry]}
    with pytest.raises(codec.CodecError, match="field 'led'"):
        codec.decode(msgpack.packb({**wire, "v": SCHEMA_VERSION}))


def test_decoded_task_path_is_a_tuple():
    env = codec.decode(codec.encode(Batch(0, 1, "p", [Envelope(Kind.TASK, "x", "y", 1, 1, 2, task())])))
    assert isinstance(env.envelopes[0].body.path, tuple)


def test_in_process_key_expressions_intersect_like_zenoh():
    from node_runtime.runtime.inproc import key_matches

    assert key_matches("z/s/events/offloaded/*", "z/s/events/*/n1")  # wildcard on both sides
    assert key_matches("z/s/events/**", "z/s/events/dropped/n1")
    assert key_matches("z/**", "z")
    assert key_matches("z/s/node/n1/state", "z/s/node/n1/state")
    assert not key_matches("z/s/events/dropped/*", "z/s/events/created/n1")
    assert not key_matches("z/s/*/state", "z/s/node/n1/state")
    assert not key_matches("z/a/alive/*", "z/a/alive/driver/x")
