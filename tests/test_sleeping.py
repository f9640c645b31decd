"""Processes sleep through ticks in which none of their roles has mail or work due (docs/protocol.md),
and that is invisible in the results."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from env import ZenohEdgeEnv
from node_runtime.model.controller import Controller
from node_runtime.model.messages import Envelope, Kind, Pending, Report, Task, TaskSize
from node_runtime.model.role import STAT_FIELDS, Outbox, Role
from node_runtime.model.spec import Scenario
from node_runtime.model.worker import COAST_TICKS, Worker
from node_runtime.model.workload import TaskSource
from orchestrator import clock as clock_module
from orchestrator.clock import HOLD_LIMIT
from orchestrator.scenario import load_scenario
from orchestrator.session import Simulation
from tests.conftest import ROOT, model_part, run_summary, same, write_scenario
from tests.test_determinism import outputs
from tests.test_env import run_episode
from tests.test_reference_semantics import everything

HEADER = "time,client,instructions,input_bytes,output_bytes,cpi,deadline\n"


def tricky(tmp_path):
    """Every timing rule that decides when a role wakes: sparse broadcasts, long epochs, batches,
    multi-hop results, full buffers, deadlines that expire while tasks wait for a decision."""
    return load_scenario(write_scenario(tmp_path, {
        "simulation": {"steps": 200, "policy": "round_robin", "mode": "batch", "batch_size": 2,
                       "decision_interval": 3, "state_interval": 4, "max_hops": 2},
        "workload": {"arrival": {"rate": 0.5}, "tasks": [{"instructions": 3e6, "input_bytes": 2e5,
                                                          "output_bytes": 2e5, "deadline": 12}]},
        "topology": {"nodes": [{"id": "a", "frequency": 1e6, "buffer": 4, "client": True, "controller": True},
                               {"id": "b", "frequency": 1e6, "buffer": 4, "client": True, "controller": True},
                               {"id": "c", "frequency": 2e6, "buffer": 6, "controller": True},
                               {"id": "d", "client": True, "worker": False}],
                     "links": [["a", "b"], ["b", "c"], ["d", "a"]]},
    }))


def test_layouts_agree_on_every_wake_rule(tmp_path):
    scenario = tricky(tmp_path)
    ref = outputs(tmp_path, scenario, "single", seed=5)
    assert ref[0]["totals"]["dropped"]["expired"] > 0 and ref[0]["totals"]["dropped"]["queue_full"] > 0
    assert ref[0]["totals"]["offloaded"] > 0
    for layout in ("per-role", "per-node"):
        assert outputs(tmp_path, scenario, layout, seed=5, layout=layout) == ref, layout


@pytest.mark.zenoh
def test_zenoh_agrees_on_every_wake_rule(tmp_path):
    scenario = tricky(tmp_path)
    ref = outputs(tmp_path, scenario, "inproc", seed=9)
    assert outputs(tmp_path, scenario, "zenoh", seed=9, transport="zenoh", layout="per-role") == ref


def test_an_idle_network_wakes_nobody(tmp_path):
    (tmp_path / "trace.csv").write_text(HEADER + "5,a,1e6,1000,1000,1,100\n")
    scenario = load_scenario(write_scenario(tmp_path, {
        "simulation": {"steps": 30, "policy": "local"},
        "workload": {"trace": "trace.csv"},
        "topology": {"nodes": [{"id": "a", "frequency": 1e6, "client": True, "controller": True},
                               {"id": "b", "frequency": 1e6}], "links": [["a", "b"]]},
    }))
    with Simulation.inproc(scenario, layout="per-role") as sim:
        sim.reset()
        assert len(sim.last) == len(sim.plan.procs)  # a reset runs everyone
        woken = []
        for _ in range(30):
            sim.step()
            woken.append(sorted(d.proc for d in sim.last))
    # 1: the controller hears the workers' first state broadcasts (sent at the reset's tick 0);
    # 5: the client creates the task; 6: its worker holds it undecided, reports it, broadcasts;
    # 7: the controller observes and decides; 8: it sends the decision; 9: the worker queues the task
    # and serves it (1e6 instructions on 1e6 instructions/s: one tick), the result leaves;
    # 10: the client completes it, the controller hears the new state; then nothing, ever
    assert woken[:10] == [["controller-a"], [], [], [], ["client-a"], ["worker-a"], ["controller-a"],
                          ["controller-a"], ["worker-a"], ["client-a", "controller-a"]]
    assert woken[10:] == [[]] * 20
    assert sim.metrics.summary()["totals"]["completed"] == 1


def test_looking_ahead_draws_what_asking_every_tick_draws(aot1):
    node = next(n.id for n in aot1.nodes if n.has("client"))

    def source():
        return TaskSource(aot1, node, np.random.default_rng(3), np.random.default_rng(4))

    every = source()
    expected = [(t, every.draws(t)) for t in range(1, 900)]
    expected = [(t, d) for t, d in expected if d]
    ahead, got, t = source(), [], 0
    while True:
        t = ahead.next_arrival(t)
        if t >= 900:
            break
        if draws := ahead.draws(t):
            got.append((t, draws))
    assert got == expected and len(got) > 50  # ~0.17 per tick over three and a half count blocks


def test_a_class_that_redefines_tick_runs_every_tick():
    sys.path.insert(0, str(ROOT / "examples"))
    try:
        from battery_worker import BatteryWorker
        from diurnal_source import DiurnalSource
    finally:
        sys.path.remove(str(ROOT / "examples"))

    class FasterServe(Worker):
        def serve(self, t, out):
            super().serve(t, out)

    class Replay(TaskSource):
        def draws(self, tick):
            return []

    assert BatteryWorker.wake is Role.wake  # its battery recharges every tick
    assert FasterServe.wake is Worker.wake  # serve only runs when Worker.wake says so
    assert DiurnalSource.next_arrival is TaskSource.next_arrival  # a rate schedule is looked ahead
    assert Replay.next_arrival(None, 7) == 8


class ServesLikeAnyWorker(Worker):
    """Serves as the built-in worker does; but a class that redefines ``serve`` might not, so it never coasts."""

    def serve(self, t, out):
        super().serve(t, out)


def with_class(sc: Scenario, kind: str, cls: type, nodes: set[str] | None = None) -> Scenario:
    """``sc`` with every role of ``kind`` (on ``nodes``, or all) of this module's class ``cls``."""
    data = sc.to_dict()
    for node in data["nodes"]:
        if kind in node["roles"] and (nodes is None or node["id"] in nodes):
            node["impls"] = [*node["impls"], [kind, f"tests.test_sleeping:{cls.__name__}"]]
    return Scenario.from_dict(data)


def never_coasting(sc: Scenario) -> Scenario:
    return with_class(sc, "worker", ServesLikeAnyWorker)


class HearsEveryState(Controller):
    """Reads each state the tick it arrives, as every controller did before they held them
    (``holds_broadcasts``): its process wakes for every state its neighbours broadcast."""

    holds_broadcasts = False


def hearing_every_state(sc: Scenario) -> Scenario:
    return with_class(sc, "controller", HearsEveryState)


def with_idle_power(sc: Scenario) -> Scenario:
    data = sc.to_dict()
    for node in data["nodes"]:
        node["idle_power_w"] = 1.5
    return Scenario.from_dict(data)


@pytest.mark.parametrize("name", ["aot2", "tricky", "idle power", "failures", "co-located queue_first"])
def test_a_coasting_worker_changes_what_a_worker_that_runs_every_tick_changes(tmp_path, monkeypatch, name):
    """A busy worker sleeps until its head task finishes (``Worker.wake``), its counters moved on by its drift,
    both where it replays the skipped ticks and in the orchestrator's tables: bit for bit the same tables as a
    worker that serves every tick, with fewer worker ticks."""
    scenario = {"aot2": lambda: load_scenario("aot2"), "tricky": lambda: tricky(tmp_path),
                "idle power": lambda: with_idle_power(tricky(tmp_path)),
                "failures": lambda: everything(tmp_path, 2), "co-located queue_first": lambda: everything(tmp_path, 0),
                }[name]()
    ran = {"ticks": 0}
    tick = Worker.tick

    def counted(self, t, inbox, out):
        ran["ticks"] += 1
        tick(self, t, inbox, out)

    monkeypatch.setattr(Worker, "tick", counted)
    coasting = outputs(tmp_path, scenario, "coasting", ticks=300, seed=3, policy="random", layout="per-node")
    coasted = ran["ticks"]
    ran["ticks"] = 0
    every = outputs(tmp_path, never_coasting(scenario), "every", ticks=300, seed=3, policy="random", layout="per-node")
    assert coasting[1:] == every[1:]  # ticks.csv, nodes.csv
    assert coasting[0]["totals"] == every[0]["totals"] and coasting[0]["totals"]["completed"] > 0
    assert coasted < ran["ticks"]


def served_alone(tmp_path, cycles: float) -> tuple[Worker, Outbox]:
    """A 1 Mcycle/s worker that admitted a task of ``cycles`` at tick 1 and served it from then, alone."""
    (tmp_path / "trace.csv").write_text(HEADER + f"1,a,{cycles},1000,1000,1,5000\n")
    scenario = load_scenario(write_scenario(tmp_path, {
        "simulation": {"steps": 10},
        "workload": {"trace": "trace.csv"},
        "topology": {"nodes": [{"id": "a", "frequency": 1e6, "buffer": 4, "client": True}], "links": []},
    }))
    worker = Worker(scenario.node["a"], scenario)
    out = Outbox(worker.id)
    out.tick = 1
    task = Task(1, "a", 1, TaskSize(cycles, 1e3, 1e3, 1.0, 5e3))
    worker.tick(1, [Envelope(Kind.TASK, "client:a", worker.id, 1, 0, 1, task)], out)
    return worker, out


def test_a_worker_coasts_to_the_tick_its_head_task_finishes(tmp_path):
    """By hand: a 3.5 Mcycle task."""
    worker, out = served_alone(tmp_path, 3.5e6)
    assert worker.wake(1) == 4  # 2.5 Mcycles left after tick 1: 1 in tick 2, 1 in tick 3, the last 0.5 in tick 4
    assert worker.drift[STAT_FIELDS.index("busy_cycles")] == 1e6 and sum(worker.drift) > 1e6  # and its energy
    out.tick = 4
    worker.tick(4, [], out)  # replays ticks 2 and 3, then finishes the task
    assert worker.stats.busy_cycles == 3.5e6 and not worker.queue and worker.drift is None
    assert [e.kind for e in out.envelopes] == [Kind.RESULT]


def test_a_long_task_coasts_in_stretches_of_at_most_coast_ticks(tmp_path):
    """Finding the finish tick takes a step per tick ahead, so a worker coasts COAST_TICKS at most, then runs a
    tick and coasts on: a 1,000-second task costs a few wake-ups, never a loop as long as the task each time."""
    worker, out = served_alone(tmp_path, 1e9)
    assert worker.wake(1) == 1 + COAST_TICKS
    out.tick = 1 + COAST_TICKS
    worker.tick(1 + COAST_TICKS, [], out)
    assert worker.stats.busy_cycles == (1 + COAST_TICKS) * 1e6 and worker.wake(1 + COAST_TICKS) == 1 + 2 * COAST_TICKS


def test_the_battery_example_agrees_across_layouts(tmp_path):
    sys.path.insert(0, str(ROOT / "examples"))
    try:
        scenario = load_scenario(ROOT / "examples" / "battery.yaml")
        ref = model_part(run_summary(scenario, ticks=300, seed=2))
        assert model_part(run_summary(scenario, ticks=300, seed=2, layout="per-role")) == ref
    finally:
        sys.path.remove(str(ROOT / "examples"))


def driven_scenarios(tmp_path):
    def quieter(sc: Scenario) -> Scenario:  # idle spells, so that controllers sleep between arrivals
        data = sc.to_dict()
        data["workload"]["arrival"]["rate"] = 0.1
        return Scenario.from_dict(data)

    return {"aot2": load_scenario("aot2"), "tricky": tricky(tmp_path), "failures": quieter(everything(tmp_path, 2)),
            "co-located": quieter(everything(tmp_path, 0))}


@pytest.mark.parametrize("name", ["aot2", "tricky", "failures", "co-located"])
def test_a_driven_controller_that_sleeps_observes_exactly_what_it_would_have(tmp_path, name):
    """An agent's controller with nothing heard but states and nothing to place sleeps; the environment
    re-times its last observation instead (``observation_at``), with the states broadcast since. At every step,
    every agent's observation equals what its controller object would observe at that tick (one that reads
    every state as it arrives, so that the object is up to date): epochs of 3 ticks, broadcasts every 4,
    batches, failures of neighbours and of the node itself, co-located control."""
    scenario = hearing_every_state(driven_scenarios(tmp_path)[name])
    env = ZenohEdgeEnv(scenario, transport="inproc", layout="per-role", max_steps=120)
    obs, _ = env.reset(seed=3)
    controllers = {r.id: r for d in env.sim.drivers for r in d.host.roles if isinstance(r, Controller)}
    rng = np.random.default_rng(0)
    retimed = slept = 0
    while env.agents:
        obs, *_ = env.step({a: rng.choice(np.flatnonzero(obs[a]["action_mask"])) if env.layouts[a].batch is None
                            else [rng.choice(np.flatnonzero(m)) for m in obs[a]["action_mask"]] for a in env.agents})
        t = env.sim.tick
        opened = len(env.sim.clock.opened)
        slept += opened < len(env.sim.plan.procs)
        for agent, role in env._role.items():
            ctrl = controllers[role]
            raw = env._raw[agent]
            if ctrl.down(t):
                assert raw is None
                continue
            assert raw == ctrl.observe(t), (agent, t)
            retimed += raw is not ctrl.last
    assert retimed > 0 and slept > 0  # the rule was exercised
    env.close()


class Urgency(Controller):
    """A user's controller that observes otherwise: the deadline pressure of its oldest undecided task,
    which grows every tick. Its observations cannot be re-timed by the built-in rule."""

    def observe(self, t: int):
        obs = super().observe(t)
        obs.undecided = len(self.undecided) * 1000 + t
        return obs


def test_a_users_controller_that_observes_otherwise_runs_every_tick_while_driven(tmp_path):
    scenario = load_scenario(write_scenario(tmp_path, {
        "name": "urgency", "roles": {"controller": f"{__name__}:Urgency"},
        "topology": {"nodes": [{"id": "a", "client": True, "controller": True}, {"id": "b", "controller": True}],
                     "links": [["a", "b"]]},
        "workload": {"arrival": {"rate": 0.05}}}))
    assert not Urgency.retimed and Controller.retimed
    env = ZenohEdgeEnv(scenario, transport="inproc", layout="per-role", max_steps=60)
    env.reset(seed=1)
    controllers = {r.id: r for d in env.sim.drivers for r in d.host.roles if isinstance(r, Controller)}
    assert controllers and all(type(c) is Urgency for c in controllers.values())
    while env.agents:
        env.step({a: 0 for a in env.agents})
        for agent, role in env._role.items():
            assert env._raw[agent] == controllers[role].observe(env.sim.tick)
    env.close()


@pytest.mark.zenoh
@pytest.mark.parametrize("name", ["failures", "co-located"])
def test_zenoh_agrees_on_re_timed_observations(tmp_path, name):
    """The re-timing over Zenoh (each link's busy-until tick on the wire) gives the in-process episode: the same
    observations, rewards and infos at every step, with sleeping controllers in a scenario of every timing rule."""
    agrees_with_one_process(driven_scenarios(tmp_path)[name], "per-role")


def agrees_with_one_process(scenario: Scenario, layout: str) -> None:
    """90 steps of ``scenario`` over Zenoh in ``layout`` give the in-process episode of one process: the same
    observations, rewards and infos at every step."""
    traces = []
    for transport, lay in (("inproc", "single"), ("zenoh", layout)):
        env = ZenohEdgeEnv(scenario, transport=transport, layout=lay, max_steps=90)
        traces.append(run_episode(env, seed=2, actions_rng_seed=4, steps=90))
        env.close()
    for i, (a, b) in enumerate(zip(*traces, strict=True)):
        assert same(a, b), f"step {i} differs"


@pytest.mark.zenoh
@pytest.mark.parametrize(("name", "limit"), [("aot2", HOLD_LIMIT), ("tricky", HOLD_LIMIT), ("tricky", 2)])
def test_zenoh_agrees_with_mail_that_waits(tmp_path, monkeypatch, name, limit):
    """Over Zenoh, a process per node: mail held until it is due (tasks on their links, a wake once ``limit``
    publications wait) and states a sleeping controller reads at its next run (they come with its tick) give the
    episode of one process, where no mail crosses processes at all: the same observations, rewards and infos at
    every step."""
    monkeypatch.setattr(clock_module, "HOLD_LIMIT", limit)
    held, handed_over = [], []
    collect = clock_module.Clock._collect

    def counted(self, opened):
        dones = collect(self, opened)
        held.extend(count for d in dones for count, _ in d.held.values())
        handed_over.extend(w for d in dones for w in d.states if w in self.state_listeners)
        return dones

    monkeypatch.setattr(clock_module.Clock, "_collect", counted)
    agrees_with_one_process(driven_scenarios(tmp_path)[name], "per-node")
    assert handed_over  # states went through the clock
    if name == "aot2":
        assert sum(held) > 0  # and mail on its links waited


@pytest.mark.parametrize("limit", [HOLD_LIMIT, 2])
@pytest.mark.parametrize("name", ["aot2", "tricky", "failures", "co-located"])
def test_states_held_until_the_next_run_change_nothing_an_agent_sees(tmp_path, monkeypatch, name, limit):
    """A sleeping controller's process holds the states its neighbours broadcast (``Done.held``) instead of
    waking for them, and the environment re-times its observations with them: observations, rewards and infos
    are those of controllers that read every state as it arrives, step for step, with fewer process runs. A
    limit of 2 wakes the processes after two held broadcasts, as ``HOLD_LIMIT`` does after many."""
    monkeypatch.setattr(clock_module, "HOLD_LIMIT", limit)
    scenario = driven_scenarios(tmp_path)[name]
    runs = {}
    for label, sc in (("held", scenario), ("every", hearing_every_state(scenario))):
        env = ZenohEdgeEnv(sc, transport="inproc", layout="per-node", max_steps=150)
        obs, infos = env.reset(seed=4)
        rng = np.random.default_rng(1)
        steps, opened = [], 0
        while env.agents:
            actions = {a: int(rng.choice(np.flatnonzero(obs[a]["action_mask"]))) if env.layouts[a].batch is None
                       else [int(rng.choice(np.flatnonzero(m))) for m in obs[a]["action_mask"]] for a in env.agents}
            obs, rewards, _, _, infos = env.step(actions)
            opened += len(env.sim.clock.opened)
            for info in infos.values():  # the scenarios differ in the controllers' class, hence in their hash
                info.get("episode", {}).pop("scenario_hash", None)
            steps.append(({a: {k: np.asarray(v).tolist() for k, v in o.items()} for a, o in obs.items()},
                          rewards, infos))
        runs[label] = steps, opened
        env.close()
    assert runs["held"][0] == runs["every"][0]
    assert runs["held"][1] < runs["every"][1]


@pytest.mark.parametrize("name", ["aot2", "tricky", "failures", "co-located queue_first"])
def test_held_states_change_no_result(tmp_path, name):
    """With node-side policies too: the tables are those of controllers that read every state as it arrives."""
    scenario = {"aot2": lambda: load_scenario("aot2"), "tricky": lambda: tricky(tmp_path),
                "failures": lambda: everything(tmp_path, 2), "co-located queue_first": lambda: everything(tmp_path, 0),
                }[name]()
    held = outputs(tmp_path, scenario, "held", ticks=300, seed=3, policy="random", layout="per-node")
    every = outputs(tmp_path, hearing_every_state(scenario), "every", ticks=300, seed=3, policy="random",
                    layout="per-node")
    assert held[1:] == every[1:]  # ticks.csv, nodes.csv
    assert held[0]["totals"] == every[0]["totals"] and held[0]["totals"]["completed"] > 0


def test_a_controller_reads_later_only_a_report_that_brings_nothing_to_place(tmp_path):
    """By hand: a report of tasks it has all placed only updates what the controller would observe, so it may
    wait unread (``Controller.reads_later``); one with a task it has not placed may not, nor anything for a
    controller that reads every state and report as it arrives."""
    scenario = tricky(tmp_path)
    controller = Controller(scenario.node["a"], scenario)
    pending = [Pending(7, "a", 1, TaskSize(3e6, 2e5, 2e5, 1.0, 12.0), 2)]
    report = Envelope(Kind.REPORT, "worker:a", controller.id, 1, 2, 3, Report(pending, [4.0, 0.0]))
    assert not controller.reads_later(report)
    controller.decided.add(7)
    assert controller.reads_later(report)
    assert controller.reads_later(Envelope(Kind.REPORT, "worker:a", controller.id, 2, 3, 4, Report([], None)))
    eager = HearsEveryState(scenario.node["a"], scenario)
    eager.decided.add(7)
    assert not eager.reads_later(report)


def test_states_go_with_the_ticks_only_from_processes_whose_every_listener_holds_them(tmp_path):
    """One node's controller reads every state as it arrives: its neighbours' states reach it as mail (and, in the
    same batch, every other listener of theirs), the others' go with the ticks. The tables are those of a run in
    which every controller reads every state as mail."""
    aot2 = load_scenario("aot2")
    mixed = with_class(aot2, "controller", HearsEveryState, {"rpi3_0"})
    with Simulation.inproc(mixed, layout="per-node") as sim:
        by_clock = {sim.plan.roles[w] for w in sim.clock.state_listeners}
    neighbours = {f"worker:{n}" for n in aot2.neighbours["rpi3_0"]}
    workers = {r for r in sim.plan.roles if r.startswith("worker:")}
    assert by_clock and neighbours.isdisjoint(by_clock) and by_clock | neighbours == workers
    every = outputs(tmp_path, hearing_every_state(aot2), "every", ticks=300, seed=3, policy="random",
                    layout="per-node")
    assert outputs(tmp_path, mixed, "mixed", ticks=300, seed=3, policy="random", layout="per-node")[1:] == every[1:]


def test_a_state_handed_over_twice_is_read_once(aot2):
    """A tick for every process carries each state any of them has yet to read: one already taken is skipped."""
    from node_runtime.runtime.host import Host
    from node_runtime.runtime.layout import ProcessLayout

    plan = ProcessLayout(aot2, "per-node")
    host = Host("node-server_0", plan)
    w = plan.role_index["worker:rpi3_0"]
    host.take_states({w: (1, 2, 12.5, 4, 7)})
    host.take_states({w: (1, 2, 12.5, 4, 7), plan.role_index["worker:server_0"]: (0, 0, 5.0, 4, 3)})  # its own: mail
    (env,) = host.mail["controller:server_0"][5]
    assert (env.kind, env.src, env.dst, env.seq, env.sent, env.arrive) == (Kind.STATE, "worker:rpi3_0",
                                                                           "state/rpi3_0", 7, 4, 5)
    assert (env.body.node, env.body.queue, env.body.occupancy, env.body.drains_at) == ("rpi3_0", 1, 2, 12.5)
    host.take_states({w: (3, 3, 20.0, 6, 9)})
    assert [e.body.queue for e in host.mail["controller:server_0"][7]] == [3]
