"""The clairvoyant bound (experiments.bound): at least the best schedule brute force finds on tiny instances,
at least what every baseline completes on generated regimes, and the normalised score by hand."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from agents import BASELINES, evaluate
from experiments import bound, suite
from experiments.common import make_env
from node_runtime.model.messages import Task, TaskSize
from orchestrator.scenario import load_scenario
from orchestrator.session import Simulation


def tiny(latency: int = 2, admission: str = "decide_first", buffer: int = 3):
    """a and c create tasks and decide; b is a fast worker between them."""
    return load_scenario({
        "simulation": {"steps": 40, "control_latency": latency, "admission": admission},
        "topology": {"nodes": [{"id": "a", "client": True, "controller": True, "frequency": 1e6, "buffer": buffer},
                               {"id": "b", "frequency": 4e6, "buffer": 10},
                               {"id": "c", "client": True, "controller": True, "frequency": 2e6, "buffer": buffer}],
                     "links": [{"between": ["a", "b"], "rate_bps": 8e6}, {"between": ["b", "c"], "rate_bps": 4e6}]}})


def brute_force(sc, trace, last_tick: int) -> int:
    """The most tasks any placement completes, each placement played out tick by tick (``play``)."""
    options = []
    for task in trace:
        targets = [t for t in sc.neighbours[task.origin] if sc.node[t].has("worker")]
        options.append([None, task.origin, *(targets if sc.node[task.origin].has("controller") else [])])
    return max(play(sc, trace, choice, last_tick) for choice in itertools.product(*options))


def play(sc, trace, choice, last_tick: int) -> int:
    """One placement under the model's rules (decide first), at their fastest: a controller places its oldest
    undecided task a tick, from created + 2 + control_latency on; FIFO links (arrival max(t + 1, ceil(start +
    bits / rate / dt))); FIFO CPUs spending capacity x dt a tick, work-conserving; a buffer holds a task from
    its admission until it leaves (offloaded, or finished) and refuses one when full; results come back the
    tick after the last cycle, or over the link. A task placed nowhere (None) is never admitted."""
    dt, lat = sc.dt, sc.control_latency
    held = {n.id: set() for n in sc.nodes}
    undecided = {n.id: [] for n in sc.nodes}
    cpu = {n.id: [] for n in sc.nodes}  # [task, cycles left], FIFO
    landing: dict[int, list[tuple[str, int]]] = {}  # tick -> (node, task) arriving over a link
    busy = dict.fromkeys(sc.link, 0.0)
    back: dict[int, int] = {}  # task -> tick its result reaches the client

    def send(src: str, dst: str, t: int, size_bytes: float) -> int:
        start = max(float(t), busy[(src, dst)])
        busy[(src, dst)] = start + size_bytes * 8 / sc.link[(src, dst)].rate_bps / dt
        return max(t + 1, math.ceil(busy[(src, dst)] - 1e-9))

    for t in range(last_tick + 1):
        for o, waiting in undecided.items():  # step 5: decisions
            ready = [i for i in waiting if trace[i].created + 2 + lat <= t]
            if ready:
                i = ready[0]
                waiting.remove(i)
                if choice[i] == o:
                    cpu[o].append([i, trace[i].size.cycles])
                else:
                    held[o].discard(i)
                    landing.setdefault(send(o, choice[i], t, trace[i].size.input_bytes), []).append((choice[i], i))
        arriving = landing.pop(t, []) + [(trace[i].origin, i) for i in range(len(trace))
                                         if trace[i].created + 1 == t and choice[i] is not None]
        for node, i in arriving:  # step 6: admission
            if len(held[node]) >= sc.node[node].buffer:
                continue
            held[node].add(i)
            mine = node == trace[i].origin and sc.node[node].has("controller")
            (undecided[node].append(i) if mine else cpu[node].append([i, trace[i].size.cycles]))
        for k, queue in cpu.items():  # step 7: CPU
            budget = sc.node[k].capacity * dt
            while queue and budget > 1e-6:
                used = min(budget, queue[0][1])
                budget -= used
                queue[0][1] -= used
                if queue[0][1] <= 1e-6:
                    i = queue.pop(0)[0]
                    held[k].discard(i)
                    o = trace[i].origin
                    back[i] = t + 1 if k == o else send(k, o, t, trace[i].size.output_bytes)
    return sum(back[i] <= min(Task(0, trace[i].origin, trace[i].created, trace[i].size).expires_at(dt) - 1, last_tick)
               for i in back)


def random_trace(rng: np.random.Generator, n: int) -> list[bound.TraceTask]:
    out = []
    for _ in range(n):
        size = TaskSize(float(rng.choice([2e6, 4e6, 8e6])), float(rng.choice([1e6, 4e6])), 1e5, 1.0,
                        float(rng.integers(6, 16)))
        out.append(bound.TraceTask(str(rng.choice(["a", "c"])), int(rng.integers(0, 6)), size))
    return sorted(out, key=lambda t: (t.created, t.origin))


@pytest.mark.parametrize("latency", [2, 0])
def test_the_bound_is_at_least_the_best_schedule_brute_force_finds(latency, monkeypatch):
    sc = tiny(latency, buffer=2)
    rng = np.random.default_rng(latency)
    tight = 0
    for _ in range(12):
        trace = random_trace(rng, 5)
        best = brute_force(sc, trace, 30)
        found = bound.solve(sc, trace, 30)
        assert found.kind == "exact"
        assert found.value >= best, (trace, found, best)
        tight += found.value == best
        with monkeypatch.context() as m:  # the rows of a large instance: only intervals up to the longest window
            m.setattr(bound, "ALL_ROWS", 0)
            assert bound.solve(sc, trace, 30).value >= found.value
    assert tight >= 6  # a bound that always said "all of them" would pass the line above: it is often exact here


def test_a_hand_computed_instance():
    """One node of 1e6 cycles/s, control latency 2: a task of 4e6 cycles created at tick c is decided at c + 4,
    served in ticks c + 4 .. c + 7, and its result arrives at c + 8. Three tasks at tick 0 with deadline 16 s:
    the CPU has ticks 4 .. 15 for 12 s of work, so all three fit; with deadline 15 s only two do."""
    sc = load_scenario({"simulation": {"steps": 40},
                        "topology": {"nodes": [{"id": "a", "client": True, "controller": True, "frequency": 1e6,
                                                "buffer": 5}]}})
    trace = [bound.TraceTask("a", 0, TaskSize(4e6, 1e6, 1e5, 1.0, d)) for d in (16.0, 16.0, 16.0)]
    assert bound.solve(sc, trace, 40).value == 3
    trace = [bound.TraceTask("a", 0, TaskSize(4e6, 1e6, 1e5, 1.0, 15.0)) for _ in range(3)]
    assert bound.solve(sc, trace, 40).value == 2
    assert bound.solve(sc, trace[:1], 7).value == 0  # the result would arrive at tick 8, after the episode
    trace = [bound.TraceTask("a", 0, TaskSize(4e6, 1e6, 1e5, 1.0, 7.0))]  # one tick short of c + 8
    assert bound.solve(sc, trace, 40).value == 0


def test_the_timing_the_bound_assumes_is_the_models_own():
    """Tasks alone on a node complete with the deadline the bound says they need, and not one tick less."""
    def run(deadline: float) -> tuple[int, int]:
        sc = load_scenario({"simulation": {"steps": 200}, "workload": {
            "arrival": {"kind": "constant", "rate": 0.02},
            "tasks": [{"instructions": 4e6, "input_bytes": 1e6, "output_bytes": 1e5, "deadline": deadline}]},
            "topology": {"nodes": [{"id": "a", "client": True, "controller": True, "frequency": 1e6}]}})
        with Simulation.inproc(sc) as sim:
            summary = sim.run(201, seed=5, policy="local")
        return summary["totals"]["completed"], bound.episode_bound(sc, 5, 200).value

    completed, value = run(8.0)  # decided at c + 4, served c + 4 .. c + 7, back at c + 8
    assert completed > 0 and value >= completed
    assert run(7.0) == (0, 0)


def test_the_trace_is_what_the_episode_creates():
    regime = suite.draw(suite.REGIMES["validation"].seeds(1)[0], "validation", 0, steps=30)
    sc = load_scenario(regime.scenario, name_hint=regime.name)
    trace = bound.arrival_trace(sc, 100_001, 31)
    with Simulation.inproc(sc) as sim:
        summary = sim.run(31, seed=100_001)
    assert len(trace) == summary["totals"]["generated"] > 0


def test_no_baseline_beats_the_bound_on_generated_regimes(tmp_path):
    paths = suite.write(suite.suite("validation", 3, steps=40), tmp_path)
    for path in paths:
        env = make_env(str(path), None, None)
        try:
            found = bound.episode_bound(env.scenario, 100_000, env.max_steps)
            for name, cls in BASELINES.items():
                row = evaluate(env, cls(0), 1)[0]
                assert row["generated"] == found.tasks
                assert row["completed"] <= found.value, (path.name, name, row["completed"], found)
        finally:
            env.close()


def test_the_normalised_score_by_hand():
    assert bound.normalised_score(30, 10, 50) == 0.5  # (30 - 10) / (50 - 10)
    assert bound.normalised_score(10, 10, 50) == 0.0 and bound.normalised_score(50, 10, 50) == 1.0
    assert bound.normalised_score(5, 10, 30) == -0.25  # below local
    assert math.isnan(bound.normalised_score(7, 7, 7))  # no room above local


def test_scenarios_outside_the_model_are_refused():
    sc = tiny().replace(max_hops=2)
    with pytest.raises(bound.BoundError, match="max_hops 2"):
        bound.solve(sc, [bound.TraceTask("a", 0, TaskSize(1e6, 1e5, 1e5, 1.0, 10.0))], 20)
    with pytest.raises(bound.BoundError, match=r"payloads \(classify\)"):  # real work: its cycles are measured
        bound.solve(load_scenario("examples/payload_classifier"), [], 20)


def test_the_command_without_a_suite_is_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        bound.main(["--suite", str(tmp_path), "--no-progress"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "manifest.csv: not found" in err


def test_a_regime_outside_the_model_stops_the_command_in_one_line(tmp_path, capsys):
    suite.write(suite.suite("test", 1, steps=20), tmp_path / "test")
    (path,) = (tmp_path / "test").glob("test-*.yaml")
    path.write_text(path.read_text().replace("max_hops: 1", "max_hops: 2"))
    with pytest.raises(SystemExit) as e:
        bound.main(["--suite", str(tmp_path / "test"), "--episodes", "1", "--no-progress"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1 and "max_hops 2; the bound models one hop" in err, err
    assert not (tmp_path / "test" / "bound.csv").exists()
