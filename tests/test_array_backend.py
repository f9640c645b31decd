"""The array backend (node_runtime/model/array.py) gives the in-process emulator's results, tick for tick.

Both run the same scenario with the same seeds and the same node-side policy; after every tick every role's
counters (the ``STAT_FIELDS``, in flight, the response times' sum) must be equal, and with them every
column of ticks.csv and nodes.csv, which the orchestrator sums from them: exactly, floats included (the
backend adds its floats in the emulator's order). CI runs a small set; ``--all`` runs every bundled
scenario the backend takes with each of its policies over a whole episode, and the settings, failures,
losses and hop limits below in full. Deliberately broken rules (a deadline one tick late, another random
stream, a result that skips its path, ...) must make the comparison fail. A tick's temporaries grow linearly
in the node count.
"""

from __future__ import annotations

import dataclasses
import math
import tracemalloc

import numpy as np
import pytest

from node_runtime.model import array
from node_runtime.model.array import FIELDS, POLICIES, ArraySim, Unsupported, refusal
from node_runtime.model.arrival import Constant, Linear, Uniform, Zigzag
from node_runtime.model.spec import Failure, Scenario
from orchestrator.metrics import COMPLETED, GENERATED, PENALISED, RT_SUM
from orchestrator.metrics import FIELDS as METRIC_FIELDS
from orchestrator.scenario import load_scenario
from orchestrator.session import Simulation
from topologies import bundled_scenarios

SMALL = [("aot1", "local", 300, 3), ("aot2", "least_queue", 250, 7), ("aot4", "round_robin", 150, 5),
         ("aot3_compute", "least_queue", 200, 2), ("aot1_urgent", "round_robin", 200, 4),
         ("aot3_compute", "greedy", 200, 6), ("aot2", "random", 200, 3), ("aot4", "greedy_backlog", 150, 3),
         ("aot3_compute", "local_first", 200, 3), ("aot2", "threshold", 300, 3), ("aot3", "drift_plus_penalty", 200, 3),
         ("aot2_reference", "least_queue", 300, 3), ("aot4_reference", "greedy_backlog", 200, 3),
         ("examples/failures", "least_queue", 200, 3),
         # a lost offload still on its lossy link when its task is gone in every copy charges the next message
         ("examples/aot2_overrides", "greedy", 260, 1)]


def first_difference(scenario: str | Scenario, policy: str, ticks: int, seed: int) -> str | None:
    """Run two copies (seeds ``seed`` and ``seed + 1``) beside two in-process simulations; the first tick,
    copy, role and field where they differ, or None."""
    sc = load_scenario(scenario) if isinstance(scenario, str) else scenario
    seeds = [seed, seed + 1]
    arr = ArraySim(sc, len(seeds), policy=policy)
    arr.reset(seeds, ticks)
    sims = [Simulation.inproc(sc) for _ in seeds]
    try:
        assert arr.roles == sims[0].plan.roles
        assert METRIC_FIELDS[:len(FIELDS)] == FIELDS
        for t in range(ticks):
            got = arr.step()
            for copy, (sim, seed_) in enumerate(zip(sims, seeds, strict=True)):
                report = sim.reset(seed_, policy=policy) if t == 0 else sim.step()
                m = np.zeros((len(arr.roles), len(METRIC_FIELDS)))
                m[:, :len(FIELDS)] = got[copy]
                m[:, PENALISED] = m[:, RT_SUM] + sim.metrics.penalty * (m[:, GENERATED] - m[:, COMPLETED])
                for what, mine, theirs in (("totals", m.sum(axis=0), report.totals),
                                           ("nodes", sim.metrics.incidence @ m, report.nodes)):
                    bad = np.argwhere(np.atleast_2d(mine != theirs))
                    if len(bad):
                        row, col = bad[0]
                        at = "network" if what == "totals" else sc.nodes[row].id
                        return (f"tick {t}, copy {copy} (seed {seed_}), {at}: {METRIC_FIELDS[col]} "
                                f"{np.atleast_2d(mine)[row, col]!r} != {np.atleast_2d(theirs)[row, col]!r}")
        return None
    finally:
        for sim in sims:
            sim.close()


@pytest.mark.parametrize(("name", "policy", "ticks", "seed"), SMALL)
def test_array_backend_gives_the_emulators_counters_tick_for_tick(name, policy, ticks, seed):
    assert first_difference(name, policy, ticks, seed) is None


# the settings the backend takes beyond the bundled scenarios' own, on aot2 (the first two in CI)
SETTINGS = [{"mode": "batch", "batch_size": 3}, {"decision_interval": 3, "state_interval": 2},
            {"mode": "batch", "batch_size": 2, "decision_interval": 2, "state_interval": 3}, {"max_hops": 0},
            {"dt": 0.5}, {"admission": "queue_first"}, {"control_latency": 0},
            {"control_latency": 0, "decision_interval": 2, "state_interval": 3},
            {"admission": "queue_first", "control_latency": 0, "mode": "batch", "batch_size": 3, "state_interval": 2}]


@pytest.mark.parametrize("changes", SETTINGS, ids=lambda c: ",".join(f"{k}={v}" for k, v in c.items()))
@pytest.mark.parametrize("policy", ["least_queue", "round_robin"])
def test_batch_mode_and_intervals(changes, policy, request):
    if SETTINGS.index(changes) >= 2 and not request.config.getoption("--all"):
        pytest.skip("the full set runs with --all")
    assert first_difference(load_scenario("aot2").replace(**changes), policy, 250, 3) is None


# arrival schedules and processes beyond the bundled aot ones (the first in CI)
ARRIVALS = [Zigzag(low=0.0, high=0.3, period=40, process="exponential_gaps"), Linear(start=0.05, end=0.4),
            Zigzag(low=0.1, high=0.4, period=50), Uniform(low=0.1, high=0.3),
            Constant(rate=0.2, process="exponential_gaps")]


@pytest.mark.parametrize("arrival", ARRIVALS, ids=lambda a: f"{a.kind}-{a.process}")
def test_arrival_schedules_and_processes(arrival, request):
    if ARRIVALS.index(arrival) and not request.config.getoption("--all"):
        pytest.skip("the full set runs with --all")
    sc = load_scenario("aot2")
    sc = sc.replace(workload=sc.workload.model_copy(update={"arrival": arrival}))
    assert first_difference(sc, "least_queue", 200, 5) is None


def with_failures(name: str, every: int, windows: tuple[tuple[int, int], ...]) -> Scenario:
    """``name`` with every ``every``-th node down in each of ``windows`` (start tick, ticks down)."""
    sc = load_scenario(name)
    return sc.replace(failures=[Failure(node=sc.nodes[n].id, at=at, duration=d)
                                for n in range(0, len(sc.nodes), every) for at, d in windows])


# failures beyond examples/failures: short outages on aot2_reference, whose long transfers keep links busy
# across them (the first in CI); longer ones on aot2 with each admission and control latency
FAILURES = [("aot2_reference", 2, ((60, 2), (150, 1)), {}), ("aot2", 3, ((30, 20), (120, 7)), {}),
            ("aot2", 3, ((30, 20), (120, 7)), {"admission": "queue_first"}),
            ("aot2", 3, ((30, 20), (120, 7)), {"control_latency": 0}),
            ("aot2", 3, ((30, 20), (120, 7)), {"decision_interval": 3, "state_interval": 2})]


@pytest.mark.parametrize("case", FAILURES, ids=lambda c: f"{c[0]}-{c[3]}")
@pytest.mark.parametrize("policy", ["least_queue", "greedy_backlog"])
def test_failures(case, policy, request):
    if FAILURES.index(case) and not request.config.getoption("--all"):
        pytest.skip("the full set runs with --all")
    name, every, windows, changes = case
    assert first_difference(with_failures(name, every, windows).replace(**changes), policy, 300, 3) is None


def lossy(name: str, loss: float) -> Scenario:
    """``name`` with every link losing each message with probability ``loss``."""
    sc = load_scenario(name)
    return sc.replace(links=[dataclasses.replace(lk, loss=loss) for lk in sc.links])


# link loss beyond examples/aot2_overrides (one lossy link): every link lossy (the first in CI)
LOSSES = [("aot2", 0.1, "least_queue"), ("aot2_reference", 0.2, "greedy_backlog"), ("aot4", 0.05, "random")]


@pytest.mark.parametrize("case", LOSSES, ids=lambda c: f"{c[0]}-{c[1]}-{c[2]}")
def test_link_loss(case, request):
    if LOSSES.index(case) and not request.config.getoption("--all"):
        pytest.skip("the full set runs with --all")
    name, loss, policy = case
    assert first_difference(lossy(name, loss), policy, 300, 3) is None


def test_loss_drawn_from_another_stream_is_caught(monkeypatch):
    """Each worker draws its losses from its radio's stream, one number per transmission on a lossy link."""
    own = array.stream
    monkeypatch.setattr(array, "stream", lambda seed, node, role: own(seed, node, role, 0 if role else 1))
    assert first_difference(lossy("aot2", 0.1), "least_queue", 200, 3) is not None


# max_hops above 1: tasks offloaded again, results relayed back along their path (the first in CI)
HOPS = [("aot4", 3, "random", {}), ("examples/grid", 3, "random", {}), ("aot2", 2, "greedy_backlog", {}),
        ("aot4", 2, "least_queue", {"admission": "queue_first", "control_latency": 0}),
        ("examples/failures", 3, "round_robin", {})]


@pytest.mark.parametrize("case", HOPS, ids=lambda c: f"{c[0]}-{c[1]}-{c[2]}-{c[3]}")
def test_several_hops(case, request):
    if HOPS.index(case) and not request.config.getoption("--all"):
        pytest.skip("the full set runs with --all")
    name, hops, policy, changes = case
    assert first_difference(load_scenario(name).replace(max_hops=hops, **changes), policy, 300, 3) is None


def test_a_result_that_skips_its_path_is_caught(monkeypatch):
    """With max_hops above 1 a result goes back along its task's path; handing it to the origin at once is caught."""
    def straight_home(self, t):
        c, i = self.arriving
        c, i = c[self.state[c, i] == array.TO_RELAY], i[self.state[c, i] == array.TO_RELAY]
        nd = self.node[c, i]
        self._send(c, i, array.TO_CLIENT, self.origin[c, i], np.full(len(c), t + 1), self.worker[nd],
                   self.worker_rank[nd])

    monkeypatch.setattr(ArraySim, "_relay", straight_home)
    assert first_difference(load_scenario("aot4").replace(max_hops=3), "random", 200, 3) is not None


def full_set() -> list[tuple[str, str]]:
    return [(name, policy) for name in bundled_scenarios() for policy in POLICIES
            if refusal(load_scenario(name), policy) is None]


@pytest.mark.slow
@pytest.mark.parametrize(("name", "policy"), full_set())
def test_every_bundled_scenario_the_backend_takes_over_a_whole_episode(name, policy, request):
    if not request.config.getoption("--all"):
        pytest.skip("the full set runs with --all")
    assert first_difference(name, policy, load_scenario(name).episode_ticks, 1) is None


def test_a_deadline_one_tick_late_is_caught(monkeypatch):
    """The comparison can fail: the backend with every task expiring one tick late differs from the emulator."""
    expiry = array.expiry_tick
    monkeypatch.setattr(array, "expiry_tick", lambda created, size, dt: expiry(created, size, dt) + 1)
    found = first_difference("aot1_urgent", "round_robin", 200, 4)
    assert found is not None and "expired" in found


def test_a_lifo_queue_is_caught(monkeypatch):
    """Serving the newest queued task first (the reference code's accident) is caught as well."""
    order = ArraySim._next_order
    monkeypatch.setattr(ArraySim, "_next_order", lambda self, count: -order(self, count))
    assert first_difference("aot2", "least_queue", 250, 7) is not None


@pytest.mark.parametrize(("name", "feature"), [("examples/payload_classifier", "payloads"),
                                               ("examples/zigzag_workload", "no worker of its own")])
def test_what_it_does_not_model_is_refused_in_one_line(name, feature):
    with pytest.raises(Unsupported) as info:
        ArraySim(load_scenario(name), 2)
    message = str(info.value)
    assert "\n" not in message and feature in message and "in-process or Zenoh backend" in message


def test_a_policy_it_does_not_run_is_refused():
    assert "'mylab:Mine'" in refusal(load_scenario("aot2"), "mylab:Mine")
    assert all(refusal(load_scenario("aot2"), policy) is None for policy in POLICIES)


def swapped(method, **values):
    """``method`` run with some of its instance's attributes replaced, each by a function of the instance (all
    computed before any is set), and restored after: a broken rule for one part of the tick."""

    def run(self, *args):
        saved = {name: getattr(self, name) for name in values}
        new = {name: value(self) for name, value in values.items()}
        for name, value in new.items():
            setattr(self, name, value)
        try:
            return method(self, *args)
        finally:
            for name, value in saved.items():
                setattr(self, name, value)

    return run


def test_a_random_policy_on_another_stream_is_caught(monkeypatch):
    """``random`` must draw the controller's own stream, draw for draw: another stream of the same seed differs."""
    own = array.stream
    monkeypatch.setattr(array, "stream", lambda seed, node, role: own(seed, node, role, 1))
    assert first_difference("aot2", "random", 200, 3) is not None


def test_backlogs_ignored_are_caught(monkeypatch):
    """greedy_backlog with every link's backlog read as empty is plain greedy, and the comparison sees it."""
    monkeypatch.setattr(ArraySim, "_by_backlog", swapped(ArraySim._by_backlog, busy=lambda s: np.zeros_like(s.busy)))
    assert first_difference("aot4", "greedy_backlog", 150, 3) is not None


def test_a_deadline_one_tick_later_for_local_first_is_caught(monkeypatch):
    """local_first keeps a task whose estimate meets its time left; a tick more of it is caught."""
    monkeypatch.setattr(ArraySim, "_by_backlog", swapped(ArraySim._by_backlog, deadline=lambda s: s.deadline + s.dt))
    assert first_difference("aot3_compute", "local_first", 200, 3) is not None


def test_a_started_task_offered_for_diversion_is_caught(monkeypatch):
    """queue_first: a task that has had cycles may not be diverted; offering it to the controller is caught."""
    never_started = swapped(ArraySim._divertible, rem=lambda s: s.cycles, serving=lambda s: np.full_like(s.serving, -1))
    monkeypatch.setattr(ArraySim, "_divertible", never_started)
    assert first_difference("aot2_reference", "least_queue", 100, 3) is not None


def test_a_colocated_controller_seeing_its_worker_as_broadcast_is_caught(monkeypatch):
    """control_latency 0: the controller reads its own worker as it is (age 0); its broadcast state is a tick
    older, and reading that is caught."""
    as_broadcast = swapped(ArraySim._seen, queued=lambda s: s.heard_late,
                           undecided=lambda s: s.heard_occupancy_late - s.heard_late)
    monkeypatch.setattr(ArraySim, "_seen", as_broadcast)
    assert first_difference("aot2_reference", "least_queue", 300, 3) is not None


def test_a_controller_back_up_that_forgets_its_last_report_is_caught(monkeypatch):
    """After a failure a controller sees what its worker last reported (tasks the failure dropped) until the
    worker's next report: forgetting them is caught."""
    fail = ArraySim._fail

    def forgetful(self, t):
        fail(self, t)
        self.ghosts.clear()

    monkeypatch.setattr(ArraySim, "_fail", forgetful)
    assert first_difference("examples/failures", "least_queue", 200, 3) is not None


def test_links_kept_through_a_failure_are_caught(monkeypatch):
    """A node that goes down resets its links: keeping their backlogs is caught."""
    fail = ArraySim._fail

    def keeps_links(self, t):
        busy = self.busy.copy()
        fail(self, t)
        self.busy[:] = busy

    monkeypatch.setattr(ArraySim, "_fail", keeps_links)
    assert first_difference(with_failures("aot2_reference", 2, ((60, 2), (150, 1))), "greedy_backlog", 100,
                            3) is not None


def tick_peak(n: int, k: int = 2, ticks: int = 100) -> int:
    """The most bytes ``ticks`` ticks of ``k`` copies allocate at once (numpy reports its arrays to tracemalloc),
    on a random-geometric scenario of ``n`` nodes (about 12 neighbours each, every node a client at 0.1
    tasks/s: its tasks and links grow as n)."""
    side = round(math.sqrt(n * math.pi * 40.0**2 / 12))
    sc = load_scenario({"name": f"rg{n}", "simulation": {"steps": ticks, "seed": 7, "policy": "least_queue"},
                        "workload": {"arrival": {"kind": "constant", "rate": 0.1}},
                        "topology": {"generator": {"kind": "random_geometric", "n": n, "radius": 40.0, "size": side,
                                                   "seed": 0, "profile": "tier0"}}}, name_hint=f"rg{n}")
    sim = ArraySim(sc, k)
    sim.reset(list(range(1, k + 1)), ticks)
    tracemalloc.start()
    try:
        for _ in range(ticks):
            sim.step()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_a_ticks_memory_grows_linearly_in_nodes():
    """Eight times the nodes: a tick's temporaries grow about eightfold (6.5 here), not 64-fold (a search of
    the charged offloads that compared every transmission with every live task grew 21-fold)."""
    assert tick_peak(1600) < 12 * tick_peak(200)
