"""Outsiders on the bus: what a process cannot decode or trust is refused, counted and logged; the run
goes on with the results a clean run gives.

In process, an attacker on the in-memory bus publishes what an outsider on the router could, at a
tick it sees opened; over Zenoh, an outside session publishes on a served run's keys (docs/bus.md,
"Rejected messages").
"""

from __future__ import annotations

import signal

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from env import ZenohEdgeEnv
from node_runtime.model.messages import Decision, Envelope, Kind, NodeState, Task, TaskSize
from node_runtime.model.role import STAT_FIELDS
from node_runtime.runtime import codec, remote
from node_runtime.runtime.aggregator import DoneAggregator
from node_runtime.runtime.inproc import InprocBus
from node_runtime.runtime.keys import Keys
from node_runtime.runtime.origin import Keyring
from node_runtime.runtime.protocol import SCHEMA_VERSION, Batch, Done, Tick
from node_runtime.runtime.zenoh_bus import ZenohTransport, zenoh_config
from orchestrator.clock import ProcessFailed
from orchestrator.session import Simulation
from tests.conftest import model_part
from tests.launcher import Launch, assert_all_gone, served
from tests.test_codec_fuzz import values
from tests.test_serve import play

TICKS, SEED, AT = 300, 4, 20
TASK = Task(1, "rpi3_0", 18, TaskSize(8e7, 1.5e8, 1.5e8, 1.0, 100.0), 0, ("rpi3_0",))
STATS = [0] * len(STAT_FIELDS)


def envelope(src: str, dst: str, sent: int, arrive: int, kind: Kind = Kind.TASK) -> Envelope:
    return Envelope(kind, src, dst, 1, sent, arrive, TASK)


def attack_at(sim: Simulation, at: int, attack) -> None:
    """Call ``attack(endpoint, episode)`` on the in-memory bus as soon as tick ``at`` is opened."""
    outsider = sim.transport.bus.endpoint()
    fired = []

    def on_tick(key: str, cmd: Tick) -> None:
        if isinstance(cmd, Tick) and cmd.command == "run" and cmd.tick == at and not fired:
            fired.append(key)
            attack(outsider, cmd.episode)

    outsider.subscribe(sim.keys.tick(), on_tick)
    outsider.subscribe(sim.keys.tick("*"), on_tick)


def node_counts(sim: Simulation) -> dict[str, int]:
    return node_counts_of(sim.drivers)


def node_counts_of(drivers) -> dict[str, int]:
    total: dict[str, int] = {}
    for driver in drivers:
        for reason, n in driver.rejections.counts.items():
            total[reason] = total.get(reason, 0) + n
    return dict(sorted(total.items()))


def test_every_refusal_in_process_leaves_the_results_alone(aot1):
    clean = model_part(Simulation.inproc(aot1, layout="per-role").run(TICKS, seed=SEED, policy="least_queue"))
    sim = Simulation.inproc(aot1, layout="per-role")
    keys, plan = sim.keys, sim.plan
    victim = next(d for d in sim.drivers if d.proc == "worker-rpi3_0")
    hosted_elsewhere = plan.role_index["worker:rpi3_5"]
    own = plan.role_index["worker:rpi3_0"]
    receiver = plan.proc_index[min(plan.recipients["worker-rpi3_0"])]
    listener = plan.listeners["worker-rpi3_0"][0]  # it hears worker:rpi3_0's states with its ticks

    def attack(out, e):
        t = AT
        # ticks: the wrong type, another episode, a reset that does not move the episode on
        out.publish(keys.tick("worker-rpi3_0"), Done("worker-rpi3_0", e, t, {}, {}))
        out.publish(keys.tick("worker-rpi3_0"), Tick(e + 3, t))
        out.publish(keys.tick("client-rpi3_0"), Tick(e, 0, "reset"))
        # states with a tick: one sent in the tick it comes with, one of a role that does not exist
        out.publish(keys.tick(listener), Tick(e, t, states={own: (0, 0, 0.0, t, 1)}))
        out.publish(keys.tick(listener), Tick(e, t, states={len(plan.roles): (0, 0, 0.0, t - 1, 1)}))
        # mail: from nobody, to a role not there, from a role its sender does not host, arriving before
        # it was sent, of an episode far ahead, sent in a tick long gone
        inbox = keys.inbox("worker-nuc_0")
        out.publish(inbox, Batch(e, t, "intruder", []))
        out.publish(inbox, Batch(e, t, "worker-rpi3_0", [envelope("worker:rpi3_0", "worker:elsewhere", t, t + 1)]))
        out.publish(inbox, Batch(e, t, "worker-rpi3_0", [envelope("client:rpi3_5", "worker:nuc_0", t, t + 1)]))
        out.publish(inbox, Batch(e, t, "worker-rpi3_0", [envelope("worker:rpi3_0", "worker:nuc_0", t, t)]))
        out.publish(inbox, Batch(e + 5, t, "worker-rpi3_0", []))
        out.publish(inbox, Batch(e, -1, "worker-rpi3_0", []))
        # a task for a state topic, on the worker's broadcast key: each process hearing it refuses it
        out.publish(keys.broadcasts("worker-rpi3_0"), Batch(e, t, "worker-rpi3_0",
                                                            [envelope("worker:rpi3_0", "state/rpi3_0", t, t + 1)]))
        # dones: the wrong type, from nobody, on another's key, with an error for a later tick
        out.publish(keys.done("worker-rpi3_0"), Tick(e, t))
        out.publish(keys.done("intruder"), Done("intruder", e, t, {}, {}))
        out.publish(keys.done("worker-rpi3_0"), Done("worker-rpi3_1", e, t, {}, {}))
        out.publish(keys.done("worker-rpi3_0"), Done("worker-rpi3_0", e, t + 1, {}, {}, error="forged failure"))

    attack_at(sim, AT, attack)
    replayed = []

    def replay(key: str, batch: Batch) -> None:  # a genuine batch (the forged ones are of tick AT), published twice
        if isinstance(batch, Batch) and batch.tick > AT and not replayed:
            replayed.append(key)
            sim.transport.bus.publish(key, batch)

    sim.transport.bus.endpoint().subscribe(keys.inbox("*"), replay)
    publish = victim.transport.publish

    raced = []

    def racing(key: str, msg, seal=None) -> None:  # reports that overtake the victim's own first Done from tick AT
        if key == victim.done_key and msg.tick >= AT and not raced:  # on, and one after it
            raced.append(msg.tick)
            t = msg.tick
            publish(key, Done(victim.proc, msg.episode, t, {}, {}))  # well formed, but without the victim's MAC
            # with the victim's key (a process that lies): its checks refuse what it may not report
            publish(key, Done(victim.proc, msg.episode, t, {}, {hosted_elsewhere: STATS}), seal)
            publish(key, Done(victim.proc, msg.episode, t, {plan.proc_index["worker-rpi3_7"]: 1}, {}), seal)
            publish(key, Done(victim.proc, msg.episode, t, {}, {}, drift={own: STATS}), seal)  # a drift without stats
            publish(key, Done(victim.proc, msg.episode, t, {}, {}, held={plan.proc_index["worker-rpi3_7"]: (1, None)}),
                    seal)
            publish(key, Done(victim.proc, msg.episode, t, {}, {}, held={receiver: (1, t + 1)}), seal)  # read next tick
            publish(key, Done(victim.proc, msg.episode, t, {}, {}, states={hosted_elsewhere: (0, 1, 0.0, 1)}), seal)
            publish(key, Done(victim.proc, msg.episode, t, {}, {}, reports={hosted_elsewhere: (t + 1, 0, None)}), seal)
            publish(key, Done(victim.proc, msg.episode, t, {}, {}, reports={own: (t, 0, None)}), seal)  # arrived
            publish(key, msg, seal)
            publish(key, msg)  # a replay: a copy of the report taken
            publish(key, Done(victim.proc, msg.episode, t, {}, {}, error="forged failure"))
        else:
            publish(key, msg, seal)

    victim.transport.publish = racing
    summary = sim.run(TICKS, seed=SEED, policy="least_queue")
    sim.close()
    assert replayed, "no genuine batch was seen to replay"
    assert raced, "the victim reported nothing from tick AT on"
    assert model_part(summary) == clean
    assert sim.transport.rejections.counts == {"bad_mac": 3, "wrong_shape": 1, "unknown_sender": 8, "wrong_tick": 3}
    expected = {"bad_mac": 4, "unknown_sender": 3 + len(plan.listeners["worker-rpi3_0"]), "wrong_shape": 1,
                "wrong_tick": 4}
    assert node_counts(sim) == expected
    # a process reports what it refused in its next Done: one that sleeps to the end (a controller with nothing
    # to place holds the states it hears) logs it as it stops instead
    reported = node_counts_of([d for d in sim.drivers if d.tick > AT])
    assert reported["bad_mac"] >= 3 and reported["wrong_tick"] >= 2 and reported["unknown_sender"] >= 3
    assert summary["run"]["rejected_messages"] == {"orchestrator": {"bad_mac": 3, "unknown_sender": 8,
                                                                    "wrong_shape": 1, "wrong_tick": 3},
                                                   "nodes": reported}


def test_a_task_of_a_type_the_scenario_lacks_is_refused_and_counted(aot1):
    """A task's type indexes workload.tasks, where a worker looks up its payload: a forged task of another
    index (aot1 has one type) is refused like any untrusted mail, and the run gives the clean results."""
    clean = model_part(Simulation.inproc(aot1, layout="per-role").run(TICKS, seed=SEED, policy="least_queue"))
    sim = Simulation.inproc(aot1, layout="per-role")
    assert len(aot1.workload.task_types) == 1

    def attack(out, e):
        for kind in (1, -1):
            forged = Task(1, "rpi3_0", AT, TASK.size, 0, ("rpi3_0",), type=kind)
            out.publish(sim.keys.inbox("worker-nuc_0"), Batch(e, AT, "worker-rpi3_0", [
                Envelope(Kind.TASK, "worker:rpi3_0", "worker:nuc_0", 1, AT, AT + 1, forged)]))

    attack_at(sim, AT, attack)
    summary = sim.run(TICKS, seed=SEED, policy="least_queue")
    sim.close()
    assert model_part(summary) == clean
    assert node_counts(sim) == {"wrong_shape": 2}
    assert next(d for d in sim.drivers if d.proc == "worker-nuc_0").rejections.last[
        sim.keys.inbox("worker-nuc_0")] == "wrong_shape (a task of type -1; the scenario has 1 task types)"


def test_mail_beyond_what_the_clock_announced_stops_the_run(aot1):
    """A forgery that passes every check cannot be told from the genuine mail: the run stops, loudly."""
    sim = Simulation.inproc(aot1, layout="per-role")

    def attack(out, e):  # client-rpi3_0 may write to controller-rpi3_0, but never does
        out.publish(sim.keys.inbox("controller-rpi3_0"), Batch(e, AT, "client-rpi3_0", [
            Envelope(Kind.DECISION, "client:rpi3_0", "controller:rpi3_0", 1, AT, AT + 1, [Decision(1, "")])]))

    attack_at(sim, AT, attack)
    with sim, pytest.raises(ProcessFailed, match=r"controller-rpi3_0 .* another publisher is on the bus"):
        sim.reset(SEED, external=["controller:rpi3_0"])
        for _ in range(AT + 2):
            sim.step({"controller:rpi3_0": 0})


HANDLED = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                            HealthCheck.function_scoped_fixture])


@pytest.fixture(scope="module")
def wired():
    """An in-process simulation at tick 10 whose clock and drivers also listen on a local Zenoh session,
    so that bytes published there take the real path: the transport's decoding, then the handlers."""
    from orchestrator.scenario import load_scenario

    sim = Simulation.inproc(load_scenario("aot1"), layout="per-node")
    sim.reset(SEED)
    for _ in range(10):
        sim.step()
    bus = ZenohTransport(zenoh_config("peer"))
    calls = []
    targets = {}

    def counted(handler):
        return lambda key, msg: (calls.append(key), handler(key, msg))

    targets[sim.keys.done("node-rpi3_0")] = sim.clock.on_done
    targets[sim.keys.dones("cluster")] = sim.clock.on_dones
    host = Keys("fuzzed-host")  # a host's aggregator, on keys of its own
    procs = ["node-rpi3_0", "node-rpi3_1"]
    aggregator = DoneAggregator(InprocBus().endpoint(), host, "cluster", procs, Keyring.new(procs, ["cluster"]))
    targets[host.host_done("cluster", "node-rpi3_0")] = aggregator.on_done
    targets[host.tick("node-rpi3_1")] = aggregator.on_tick
    for driver in sim.drivers:
        targets[sim.keys.tick()] = driver.on_tick
        targets[sim.keys.tick(driver.proc)] = driver.on_tick
        targets[sim.keys.inbox(driver.proc)] = driver.on_batch
    targets[sim.keys.broadcasts("node-rpi3_0")] = next(d for d in sim.drivers if d.proc == "node-nuc_0").on_batch
    for key, handler in targets.items():
        bus.subscribe(key, counted(handler))
    yield bus, sorted(targets), calls
    bus.close()
    sim.close()


@HANDLED
@given(st.data(), st.binary(max_size=64) | values.map(lambda v: msgpack.packb(v, use_bin_type=True))
       | st.builds(lambda kind, fields: msgpack.packb({**fields, "type": kind, "v": SCHEMA_VERSION}),
                   st.sampled_from(["tick", "done", "batch", "dones"]),
                   st.dictionaries(st.sampled_from(["e", "t", "cmd", "expect", "actions", "seed", "external",
                                                    "policy", "proc", "sent", "stats", "rt", "fl", "wake", "obs",
                                                    "error", "src", "msgs", "group", "dones"]), values)))
def test_handlers_take_anything(wired, data, payload):
    """Whatever is published on a key, the clock and the drivers refuse it or take it; nothing escapes."""
    bus, keys, calls = wired
    key = data.draw(st.sampled_from(keys))
    before = len(calls) + bus.rejections.total
    bus.put(key, payload)
    bus.dispatch(until=lambda: len(calls) + bus.rejections.total > before, timeout=10)


@pytest.mark.zenoh
def test_garbage_on_every_kind_of_key_over_zenoh(aot1):
    """Real processes; an outside session on the router publishes on clock/done, a tick key, an inbox
    key and a broadcast key. Every message is refused and counted; the results are a clean run's."""
    clean = model_part(Simulation.inproc(aot1).run(TICKS, seed=SEED, policy="random"))
    with Simulation.over_zenoh(aot1, layout="per-node") as sim:  # offloads: the listeners get work
        keys, plan = sim.keys, sim.plan
        report = sim.reset(SEED, policy="random")
        outsider = ZenohTransport.client(sim.endpoint)
        try:
            done, tick = keys.done("node-rpi3_0"), keys.tick("node-rpi3_0")
            inbox, state = keys.inbox("node-rpi3_0"), keys.broadcasts("node-rpi3_0")
            outsider.wait_matching([done, tick, inbox, state], 30)
            for key in (done, tick, inbox, state):
                outsider.put(key, b"\xc1 not msgpack")
            outsider.put(done, msgpack.packb({**codec.to_wire(Tick(0, 1)), "v": SCHEMA_VERSION + 1}))
            outsider.publish(done, Tick(0, 1))
            outsider.publish(done, Done("node-rpi3_0", 0, 10**6, {}, {}, error="forged failure"))
            outsider.publish(done, Done("node-rpi3_1", 0, 1, {}, {}))
            outsider.publish(tick, Tick(7, 1))
            outsider.publish(inbox, Batch(0, 1, "intruder", [
                Envelope(Kind.STATE, "worker:x", "state/x", 1, 1, 2, NodeState("x", 0, 0))]))
        finally:
            outsider.close()
        # processes report their counts in their next Done; a listener of node-rpi3_0 with nothing to do sleeps
        # (it holds the states it hears), so only those that ran since can have told the clock
        garbage_at, ran = report.tick, set()
        while report.tick < TICKS - 1:
            report = sim.step()
            if report.tick > garbage_at + 1:
                ran.update(d.proc for d in sim.last)
        summary = sim.summary()
    listened = ran.intersection(plan.listeners["node-rpi3_0"])
    assert "node-rpi3_0" in ran and listened
    assert model_part(summary) == clean
    assert summary["run"]["rejected_messages"] == {
        "orchestrator": {"bad_mac": 1, "bad_msgpack": 1, "schema_version": 1, "unknown_sender": 1, "wrong_shape": 1},
        "nodes": {"bad_mac": 1, "bad_msgpack": 2 + len(listened), "unknown_sender": 1}}


@pytest.mark.zenoh
def test_a_served_run_logs_garbage_and_serves_on(tmp_path):
    """The orchestrator of `launch --serve` refuses garbage on clock/done with one log line naming the
    key and the reason, then an attached environment plays the episode a clean local one plays."""
    run = Launch("aot1", "--serve", "--episodes", "1", "--steps", "20", "--layout", "per-node", "--out", str(tmp_path))
    run.wait_for("serving until Ctrl-C")
    children = run.descendants()
    endpoint, sim = served(run)
    outsider = ZenohTransport.client(endpoint)
    key = f"zedge/{sim}/clock/done/node-rpi3_0"
    try:
        outsider.wait_matching([key], 30)
        outsider.put(key, b"\x00\xff garbage")
    finally:
        outsider.close()
    run.wait_for(f"zenohedge: orchestrator rejected a message on {key}: bad_msgpack (not msgpack")

    env = ZenohEdgeEnv(connect=endpoint, sim_id=sim, max_steps=30)
    obs, rewards, summary = play(env, seed=3, steps=30)
    env.close()
    local = ZenohEdgeEnv("aot1", transport="inproc", max_steps=30)
    local_obs, local_rewards, local_summary = play(local, seed=3, steps=30)
    local.close()
    assert rewards == local_rewards and model_part(summary) == model_part(local_summary)
    assert all(np.array_equal(obs[a][k], local_obs[a][k]) for a in obs for k in obs[a])

    run.proc.send_signal(signal.SIGTERM)
    assert run.finish(30) == 130
    assert not any("Traceback" in line for line in run.err), "".join(run.err)
    assert_all_gone(children)


@pytest.mark.zenoh
def test_another_schema_version_is_refused_with_its_reason(tmp_path, monkeypatch, capsys):
    """A zenohedge-node of another ZenohEdge version (its messages carry another schema version) is told why."""
    run = Launch("aot1", "--serve", "--episodes", "0", "--out", str(tmp_path))
    run.wait_for("serving until Ctrl-C")
    children = run.descendants()
    endpoint, sim = served(run)
    monkeypatch.setattr(codec, "SCHEMA_VERSION", SCHEMA_VERSION + 1)
    assert remote.run_group(endpoint, Keys(sim), "edge", timeout=30) == remote.EXIT_USAGE
    assert capsys.readouterr().err.strip() == (
        f"zenohedge-node: simulation '{sim}' at {endpoint}: zedge/{sim}/session refused the request: schema version "
        f"{SCHEMA_VERSION + 1}, expected {SCHEMA_VERSION}: every host needs the same ZenohEdge version")
    run.wait_for(f"zenohedge: orchestrator rejected a message on zedge/{sim}/session: schema_version")
    run.proc.send_signal(signal.SIGTERM)
    assert run.finish(30) == 130
    assert_all_gone(children)
