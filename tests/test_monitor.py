"""`orchestrator monitor`, the bus contract of docs/bus.md, and examples/subscriber.py.

What matters most: a monitor attaches and detaches at any time without changing the run, receives
every tick while attached, and sees nothing of another simulation on the same Zenoh network.
Every wait is on a message, a liveliness token or a printed line, with a timeout that fails loudly.
"""

from __future__ import annotations

import json
import os
import queue
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from typing import Any

import numpy as np
import pytest
import zenoh
from rich.console import Console

from node_runtime.runtime import codec
from node_runtime.runtime.keys import Keys
from node_runtime.runtime.process import ORCHESTRATOR
from node_runtime.runtime.protocol import SCHEMA_VERSION
from node_runtime.runtime.zenoh_bus import ZenohTransport, free_port, zenoh_config
from orchestrator.scenario import load_scenario
from orchestrator.session import Simulation
from orchestrator.units import si
from orchestrator.viewers.monitor import WINDOW_TICKS, BusMonitor, DashboardState, Follower, main, queue_bar, render
from tests.conftest import ROOT, model_part, run_summary
from tests.launcher import TIMEOUT, Launch, Output, assert_all_gone, served


def monitor_cli(*args: str) -> Output:
    return Output(sys.executable, "-m", "orchestrator.viewers.monitor", *args)


def stop_server(run: Launch, children: list) -> None:
    run.proc.send_signal(signal.SIGTERM)
    assert run.finish(30) == 130
    assert_all_gone(children)


# ----- the dashboard, from recorded messages (no Zenoh) -----

def record(example: str, ticks: int) -> tuple[list[dict], list[dict]]:
    """Metrics records and offload events of an example's first ``ticks`` ticks, as they go on the wire
    (encoded, decoded).

    The in-process bus carries the same messages a Zenoh run publishes; subscribing to it switches
    them on exactly as a monitor's subscription does."""
    records, offloads = [], []
    with Simulation.inproc(load_scenario(ROOT / "topologies" / "examples" / f"{example}.yaml")) as sim:
        sim.transport.subscribe(sim.keys.metrics(), lambda key, m: records.append(codec.decode(codec.encode(m))))
        sim.transport.subscribe(sim.keys.events("offloaded"),
                                lambda key, e: offloads.append(codec.decode(codec.encode(e))))
        sim.run(ticks)
    assert [r["tick"] for r in records] == list(range(ticks))
    return records, offloads


@pytest.fixture(scope="module")
def recorded() -> tuple[list[dict], list[dict]]:
    """150 ticks of the failures example."""
    return record("failures", 150)


def replay(records: list[dict], offloads: list[dict], ticks_per_s: float = 20.0) -> DashboardState:
    """Feed the messages in their tick order, as if they arrived at ``ticks_per_s``."""
    state = DashboardState("5ca1ab1e", "failures")
    by_tick: dict[int, list[dict]] = {}
    for e in offloads:
        by_tick.setdefault(e["tick"], []).append(e)
    for i, rec in enumerate(records):
        for e in by_tick.get(rec["tick"], []):
            state.add_offload(e)
        state.add_metrics(rec, now=i / ticks_per_s)
    return state


def screen(state: DashboardState, now: float) -> str:
    console = Console(record=True, width=120, file=open(os.devnull, "w"))  # noqa: SIM115 (closed with console)
    console.print(render(state, now))
    console.file.close()
    return console.export_text()


def test_dashboard_renders_recorded_messages(recorded, tmp_path):
    records, offloads = recorded
    state = replay(records, offloads)
    last = records[-1]
    text = screen(state, now=(len(records) - 1) / 20.0)
    (tmp_path / "dashboard.txt").write_text(text)  # what a terminal shows, for whoever debugs this

    assert "5ca1ab1e" in text and "failures" in text
    assert f"tick           {last['tick']} ({last['time_s']:.3g} s simulated), episode 0 · 20.0 ticks/s" in text
    window = records[-WINDOW_TICKS:]
    dt = last["time_s"] / last["tick"]
    rates = {k: sum(r["delta"][k] for r in window) / (len(window) * dt) for k in last["delta"]}
    assert (f"gen {rates['generated']:.2f}  done {rates['completed']:.2f}  drops {rates['dropped']:.2f}  "
            f"offl {rates['offloaded']:.2f}  (last {WINDOW_TICKS} ticks)") in text
    times = [t for r in records for t in r["response_times"]][-1000:]
    p50, p95 = np.percentile(times, [50, 95])
    assert f"p50 {p50:.2f} s  p95 {p95:.2f} s  (last {len(times)} completions)" in text
    totals = last["totals"]
    dropped = totals["dropped"]
    assert f"dropped        {sum(dropped.values())} = queue full {dropped['queue_full']} + expired " in text
    assert (f"energy         {si(totals['energy_j'], 'J')} = compute {si(totals['energy_j_compute'], 'J')} + idle "
            f"{si(totals['energy_j_idle'], 'J')} + radio {si(totals['energy_j_transmit'], 'J')}") in text
    assert f"now            in the system {totals['in_system']}  overloaded nodes 0 of 5" in text

    nodes = last["nodes"]
    for i, nid in enumerate(nodes["id"]):  # one row per node: its queue bar, occupancy and counters
        occ, buf = nodes["queue"][i] + nodes["undecided"][i], nodes["buffer"][i]
        bar = queue_bar(occ, buf).plain
        assert len(bar) == 16 and bar.count("█") == round(16 * occ / buf)
        row = next(line for line in text.splitlines() if line.strip().startswith(nid + " "))
        assert bar in row and f"{occ}/{buf}" in row
        assert row.split()[-5:] == [str(nodes["completed"][i]), str(nodes["dropped"][i]), str(nodes["offloaded"][i]),
                                    f"{100 * np.mean([r['nodes']['utilisation'][i] for r in window]):.0f}", "%"]

    flows = Counter((e["node"], e["to"]) for e in offloads if e["tick"] > last["tick"] - WINDOW_TICKS)
    assert flows, "the scenario's least_queue policy offloads"
    (src, dst), n = min(flows.items(), key=lambda kv: (-kv[1], kv[0]))  # the busiest pair is listed first
    assert any(line.split() == [src, "→", dst, str(n)] for line in text.splitlines())


def test_dashboard_marks_overload_idle_and_gaps(recorded):
    records, _ = recorded
    state = replay(records[:50], [])
    assert "OVERLOAD" not in screen(state, now=49 / 20.0)
    hot = json.loads(json.dumps(records[52]))
    hot["nodes"]["overloaded"][2] = 1
    hot["totals"]["overloaded_nodes"] = 1
    state.add_metrics(hot, now=52 / 20.0)  # ticks 50 and 51 never arrived
    text = screen(state, now=60.0)
    row = next(line for line in text.splitlines() if line.strip().startswith(hot["nodes"]["id"][2] + " "))
    assert "OVERLOAD" in row
    assert "overloaded nodes 1 of 5" in text
    assert "missed         2 tick(s) lost on the way" in text
    assert "no tick for 57 s: episode over or paused" in text
    empty = screen(DashboardState("5ca1ab1e"), now=0.0)
    assert "waiting for the first tick" in empty


def test_response_time_says_what_the_episode_completed_before_attaching(recorded):
    """--once sees one tick: its percentiles cover only the completions seen, the totals the episode."""
    records, _ = recorded
    late = next(r for r in records if r["totals"]["completed"] and not r["response_times"])
    state = DashboardState("5ca1ab1e", "failures")
    state.add_metrics(late, now=0.0)
    assert (f"response time  no completion since attaching ({late['totals']['completed']} earlier in this "
            "episode)") in screen(state, now=0.0)
    state = DashboardState("5ca1ab1e", "failures")
    state.add_metrics(records[0], now=0.0)
    assert records[0]["totals"]["completed"] == 0 and "response time  no completion yet" in screen(state, now=0.0)


def test_dashboard_shows_the_jobs_of_a_scenario_of_jobs(recorded):
    """Where the records carry the job metrics (docs/bus.md), the dashboard shows them: their rates, counts and
    ratios; a scenario without jobs shows none."""
    records, offloads = record("dag_jobs", 150)
    last = records[-1]
    totals = last["totals"]
    assert totals["jobs_completed"] > 0, "150 ticks complete some jobs"
    text = screen(replay(records, offloads), now=(len(records) - 1) / 20.0)
    window = records[-WINDOW_TICKS:]
    rates = {k: sum(r["delta"][k] for r in window) / (len(window) * last["time_s"] / last["tick"])
             for k in ("jobs", "jobs_completed", "jobs_missed")}
    assert (f"jobs {rates['jobs']:.2f}  jdone {rates['jobs_completed']:.2f}  jmiss {rates['jobs_missed']:.2f}  "
            f"(last {WINDOW_TICKS} ticks)") in text
    assert (f"jobs           jobs {totals['jobs']}  jobs completed {totals['jobs_completed']}  jobs missed "
            f"{totals['jobs_missed']}") in text
    assert (f"jobs so far    job completion ratio {100 * totals['job_completion_ratio']:.1f} %  makespan (mean) "
            f"{totals['makespan']:.2f} s  penalised makespan {totals['penalised_makespan']:.2f} s") in text
    assert "job" not in screen(replay(*recorded), now=(len(recorded[0]) - 1) / 20.0)


def test_dashboard_counts_the_drops_on_broken_links_where_nodes_move():
    """Moving nodes' records carry drops on broken links: the breakdown of drops names them; elsewhere not."""
    records, offloads = record("mobile", 400)
    broken = next(i for i, r in enumerate(records) if r["totals"]["dropped"]["link_broken"])
    dropped = records[broken]["totals"]["dropped"]
    text = screen(replay(records[:broken + 1], offloads), now=broken / 20.0)
    assert (f"dropped        {sum(dropped.values())} = queue full {dropped['queue_full']} + expired "
            f"{dropped['expired']} + node failure {dropped['node_failure']} + link loss {dropped['link_loss']} + "
            f"link broken {dropped['link_broken']}") in text


def test_new_episode_restarts_the_windows(recorded):
    records, _ = recorded
    state = replay(records[:30], [])
    again = dict(records[0], episode=1)
    state.add_metrics(again, now=10.0)
    assert state.missed == 0 and len(state.deltas) == 1 and state.tick_rate() is None


# ----- the bus side, on the in-process bus (no router, no process) -----

def test_monitor_follows_an_in_process_simulation():
    """Discovery, the session query, metrics and offload events into the dashboard, detaching and the
    end of the simulation: the monitor's whole bus side, on the in-process bus."""
    with Simulation.inproc(load_scenario(ROOT / "topologies" / "examples" / "failures.yaml")) as sim:
        sim.reset(seed=3)
        for _ in range(20):
            sim.step()
        assert not sim.live.listened  # nobody watches: no metrics record is even built
        bus = BusMonitor(sim.transport.bus.endpoint(), "the in-process bus")
        [info] = bus.discover()
        assert (info.sim_id, info.scenario, info.dt) == (sim.keys.sim_id, "failures", 1.0)
        follower = Follower(info, as_json=False, once=False, console=Console(file=open(os.devnull, "w")))  # noqa: SIM115
        bus.follow(info.sim_id, follower.on_metrics, follower.on_alive, follower.on_offload)
        bus.dispatch(lambda: follower.announced, timeout=TIMEOUT)
        assert sim.live.listened
        offloaded_before = sim.summary()["totals"]["offloaded"]
        for _ in range(60):
            sim.step()
        bus.dispatch(lambda: follower.state.record["tick"] == 80, timeout=TIMEOUT)
        state, totals = follower.state, sim.summary()["totals"]
        assert len(state.deltas) == 60 and state.missed == 0
        assert state.record["totals"]["completed"] == totals["completed"]
        assert len(state.offloads) == totals["offloaded"] - offloaded_before > 0
        assert f"sim {info.sim_id} · failures" in screen(state, now=time.monotonic())
        bus.close()
        assert not sim.live.listened  # detached: records are no longer built

        watcher = BusMonitor(sim.transport.bus.endpoint(), "the in-process bus")
        watcher.follow(info.sim_id, lambda key, m: None, follower.on_alive)
        assert not follower.ended
    assert follower.ended  # the orchestrator's token went with the simulation


# ----- command-line errors -----

def test_user_errors_are_one_line_exit_2(capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))  # a registry of its own, empty: nothing launched here
    assert main([]) == 2
    dead = f"tcp/127.0.0.1:{free_port()}"
    assert main(["--connect", dead]) == 2
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = ZenohTransport.router(endpoint)  # a Zenoh network with no simulation on it
    try:
        assert main(["--connect", endpoint]) == 2
        assert main(["--connect", endpoint, "--sim", "nope"]) == 2
    finally:
        router.close()
    assert capsys.readouterr().err.splitlines() == [
        "monitor: no simulation running on this host; start one with `orchestrator launch SCENARIO --serve`, or "
        "give --connect ENDPOINT to watch one on another host",
        f"monitor: cannot reach {dead}: no Zenoh router answers there",
        f"monitor: no simulation running at {endpoint}; start one with `orchestrator launch SCENARIO --serve`, "
        "or check --connect and --prefix",
        f"monitor: no simulation 'nope' at {endpoint} (running: none)",
    ]
    for args, error in ((["--connect", "localhost"], "argument --connect: expected an endpoint such as "
                                                     "tcp/10.0.0.1:7447 (got 'localhost')"),
                        (["--sim", "a/b"], "argument --sim: expected letters, digits, '_', '.' or '-' (got 'a/b')"),
                        (["--prefix", "zedge/*"], "argument --prefix: expected key chunks without wildcards, "
                                                  "such as zedge (got 'zedge/*')")):
        with pytest.raises(SystemExit) as exited:
            main(args)
        assert exited.value.code == 2
        assert capsys.readouterr().err.splitlines()[-1] == f"orchestrator monitor: error: {error}"


# ----- against real runs -----

@pytest.mark.zenoh
@pytest.mark.slow
def test_attach_mid_run_sees_every_tick_and_changes_nothing(tmp_path):
    run = Launch("aot1", "--serve", "--episodes", "1", "--steps", "3000", "--out", str(tmp_path))
    run.wait_for("processes ready")
    children = run.descendants()
    endpoint, sim = served(run)

    def attach(until: Any) -> tuple[list[dict], list[dict]]:
        """Attach, receive until ``until(ticks)``, detach. Also asks for every event, which switches the
        node processes' event publishing on: that must not change the run either."""
        ticks: list[dict] = []
        events: list[dict] = []
        bus = BusMonitor.connect(endpoint)
        try:
            assert [i.label() for i in bus.discover()] == [f"{sim} (aot1)"]
            bus.follow(sim, lambda key, m: ticks.append(m), lambda key, alive: None)
            bus.transport.subscribe(Keys(sim).events(), lambda key, e: events.append(e))
            bus.dispatch(until=lambda: bool(ticks) and until(ticks), timeout=TIMEOUT)
        finally:
            bus.close()
        return ticks, events

    first, _ = attach(lambda ticks: len(ticks) >= 20)
    second, events = attach(lambda ticks: ticks[-1]["tick"] >= min(ticks[0]["tick"] + 300, 2999))
    numbers = [m["tick"] for m in second]
    assert numbers[0] > first[-1]["tick"], "the second attach happens mid-run, after the first detached"
    assert numbers == list(range(numbers[0], numbers[-1] + 1)), "a tick was missed while attached"
    assert {(m["type"], m["sim"], m["episode"]) for m in first + second} == {("metrics", sim, 0)}
    assert {e["kind"] for e in events} >= {"created", "dropped"} and {e["episode"] for e in events} == {0}

    run.wait_for("serving until Ctrl-C", timeout=600)
    watched = json.loads((tmp_path / "summary.json").read_text())
    alone = run_summary(load_scenario("aot1"), 3000)  # the same emulation with nobody watching
    assert model_part(watched) == model_part(alone)
    stop_server(run, children)


@pytest.mark.zenoh
def test_two_simulations_on_one_network_stay_apart(tmp_path):
    """Two simulations with different ids on ONE Zenoh network; a monitor of one sees nothing of the other.

    `orchestrator launch` always opens its own router and cannot join another one, so two launches are
    two networks. A Zenoh router of the test's own, connected to both, links them into one network:
    routers forward by key expression across router links, so every session of either simulation
    (its node processes, a driver, a monitor) now reaches the other's keys. A spy subscribed to
    `zedge/*/metrics/tick` through B's router sees both simulations' ticks; the monitor attached to A
    through A's router discovers both, and receives A's ticks only. Both are driven tick by tick from
    here (`Simulation.attach`), so what each subscriber must have seen is known exactly.
    """
    runs = [Launch("aot1", "--serve", "--episodes", "0", "--layout", "single", "--out", str(tmp_path / n))
            for n in "ab"]
    for run in runs:
        run.wait_for("serving until Ctrl-C")
    children = [c for run in runs for c in run.descendants()]
    (end_a, sim_a), (end_b, sim_b) = (served(run) for run in runs)
    hub = zenoh.open(zenoh_config("router", listen=[f"tcp/127.0.0.1:{free_port()}"], connect=[end_a, end_b]))
    spy = ZenohTransport.client(end_b)
    bus = BusMonitor.connect(end_a)
    try:
        orchestrators: set[str] = set()
        spy.watch_tokens(f"zedge/*/alive/{ORCHESTRATOR}", lambda key, alive: alive and orchestrators.add(key))
        spy.dispatch(until=lambda: len(orchestrators) == 2, timeout=TIMEOUT)  # the hub has linked them

        assert sorted(i.label() for i in bus.discover()) == sorted([f"{sim_a} (aot1)", f"{sim_b} (aot1)"])
        status, _, [line] = monitor_cli("--connect", end_a).finish()
        assert status == 2
        assert line.startswith(f"monitor: 2 simulations at {end_a}: ") and line.endswith("; choose one with --sim ID")
        assert f"{sim_a} (aot1)" in line and f"{sim_b} (aot1)" in line

        seen_by_spy: list[tuple[str, int]] = []
        seen_by_monitor: list[dict] = []
        spy.subscribe("zedge/*/metrics/tick", lambda key, m: seen_by_spy.append((m["sim"], m["tick"])))
        bus.follow(sim_a, lambda key, m: seen_by_monitor.append(m), lambda key, alive: None)
        for endpoint, sim in ((end_b, sim_b), (end_a, sim_a)):  # B first: the monitor of A is listening
            with Simulation.attach(endpoint, sim) as driver:
                driver.transport.dispatch(until=lambda d=driver: d.live.listened, timeout=TIMEOUT)
                driver.run(20)
            spy.dispatch(until=lambda s=sim: sum(k == s for k, _ in seen_by_spy) == 20, timeout=TIMEOUT)
        bus.dispatch(until=lambda: len(seen_by_monitor) >= 20, timeout=TIMEOUT)

        assert sorted(seen_by_spy) == sorted((s, t) for s in (sim_a, sim_b) for t in range(20))
        assert [(m["sim"], m["tick"]) for m in seen_by_monitor] == [(sim_a, t) for t in range(20)]
    finally:
        bus.close()
        spy.close()
        hub.close()
    for run in runs:
        run.proc.send_signal(signal.SIGTERM)
    assert [run.finish(30) for run in runs] == [130, 130]
    assert_all_gone(children)


@pytest.mark.zenoh
def test_monitor_leaves_cleanly_when_the_simulation_ends(tmp_path):
    run = Launch("aot1", "--serve", "--episodes", "0", "--layout", "single", "--out", str(tmp_path))
    run.wait_for("serving until Ctrl-C")
    children = run.descendants()
    endpoint, sim = served(run)
    mon = monitor_cli("--connect", endpoint)
    mon.wait_err("attached to")
    stop_server(run, children)
    status, out, err = mon.finish()
    assert (status, err) == (0, [f"monitor: simulation {sim} ended: its orchestrator left"])
    assert any("waiting for the first tick" in line for line in out)  # the last frame (no terminal: only that)


@pytest.fixture(scope="module")
def ticking(tmp_path_factory) -> tuple[str, str]:
    """A served aot1 run paced at 20 ticks/s, long enough to outlast the tests that watch it."""
    run = Launch("aot1", "--serve", "--tick-rate", "20", "--steps", "100000", "--layout", "per-node", "--out",
                 str(tmp_path_factory.mktemp("ticking")))
    run.wait_for("processes ready")
    children = run.descendants()
    yield served(run)
    stop_server(run, children)


@pytest.mark.zenoh
def test_example_subscriber_as_documented(ticking):
    endpoint, sim = ticking
    sub = Output(sys.executable, "examples/subscriber.py", endpoint, sim)
    ticks, drops = [], []
    while len(ticks) < 3 or not drops:
        line = sub.line()
        if line.startswith("tick "):
            ticks.append(int(line.split()[1].rstrip(":")))
            assert " generated " in line and " completed " in line and " in system " in line
        else:
            assert line.startswith("  dropped task ") and line.rstrip().endswith(": queue_full"), line
            drops.append(line)
    assert ticks == list(range(ticks[0], ticks[0] + len(ticks)))
    assert sub.finish(signal.SIGINT)[::2] == (0, [])


@pytest.mark.zenoh
def test_monitor_json_prints_every_tick(ticking):
    endpoint, sim = ticking
    mon = monitor_cli("--connect", endpoint, "--json")
    records = [json.loads(mon.line()) for _ in range(5)]
    assert [r["tick"] for r in records] == list(range(records[0]["tick"], records[0]["tick"] + 5))
    assert {(r["v"], r["type"], r["sim"]) for r in records} == {(SCHEMA_VERSION, "metrics", sim)}
    assert records[0]["nodes"]["id"] == [n.id for n in load_scenario("aot1").nodes]
    assert mon.finish(signal.SIGINT)[::2] == (0, [f"monitor: attached to {sim} (aot1) at {endpoint} (Ctrl-C to "
                                                  "detach)", f"monitor: detached from {sim}"])

    status, out, _ = monitor_cli("--connect", endpoint, "--sim", sim, "--json", "--once").finish()
    assert status == 0 and [json.loads(line)["sim"] for line in out] == [sim]


@pytest.mark.zenoh
@pytest.mark.parametrize("command", ["examples/subscriber.py {endpoint} {sim}",
                                     "-m orchestrator.viewers.monitor --connect {endpoint} --json"])
def test_piped_into_head_they_stop_quietly(ticking, command):
    """`… | head`: when the reader has gone, the writer leaves with status 0 and no traceback."""
    endpoint, sim = ticking
    shell = f"set -o pipefail; {sys.executable} {command.format(endpoint=endpoint, sim=sim)} | head -n 2"
    done = subprocess.run(["bash", "-c", shell], cwd=ROOT, capture_output=True, text=True, timeout=TIMEOUT)
    assert done.returncode == 0, done.stderr
    assert len(done.stdout.splitlines()) == 2
    assert "Traceback" not in done.stderr and "Error" not in done.stderr, done.stderr


@pytest.mark.zenoh
@pytest.mark.skipif(shutil.which("tmux") is None, reason="needs tmux")
def test_dashboard_in_a_terminal(ticking, tmp_path):
    """The real dashboard in a real terminal (tmux): the screen shows nodes, queue bars and the tick rate."""
    endpoint, sim = ticking
    name = f"zedge-monitor-{os.getpid()}"
    fifo = tmp_path / "pane"
    os.mkfifo(fifo)
    command = (f"read go; stty size; {sys.executable} -m orchestrator.viewers.monitor --connect {endpoint}; "
               "echo monitor-exit=$?; read done")
    tmux = ["tmux", "-L", name, "-f", os.devnull]  # a server of our own, without anybody's configuration
    subprocess.run([*tmux, "new-session", "-d", "-s", name, "-x", "100", "-y", "50", "-c", str(ROOT), command],
                   check=True)
    try:
        subprocess.run([*tmux, "pipe-pane", "-t", name, "-o", f"cat > {fifo}"], check=True)
        stream = bytearray()
        chunks: queue.SimpleQueue[bytes] = queue.SimpleQueue()

        def pump() -> None:
            with open(fifo, "rb") as fh:
                while chunk := fh.read1(65536):
                    chunks.put(chunk)

        threading.Thread(target=pump, daemon=True).start()

        def wait_for(pattern: bytes) -> None:
            """Until the terminal output matches ``pattern`` (what tmux hands the pane, escapes included)."""
            deadline = time.monotonic() + TIMEOUT
            while not re.search(pattern, stream):
                left = deadline - time.monotonic()
                assert left > 0, f"{pattern!r} not shown within {TIMEOUT} s: {bytes(stream[-2000:])!r}"
                try:
                    stream.extend(chunks.get(timeout=left))
                except queue.Empty:
                    continue

        subprocess.run([*tmux, "send-keys", "-t", name, "Enter"], check=True)
        wait_for(rb"\d+ \d+")
        assert b"50 100" in stream, f"the pane is not 100x50: {bytes(stream)!r}"
        wait_for(rb"(?s)\d ticks/s.*offloads? over the last")  # a whole frame with a measured tick rate was drawn
        deadline = time.monotonic() + TIMEOUT
        while True:  # the dashboard redraws in place, so a capture may catch a frame half drawn: take the next
            shown = subprocess.run([*tmux, "capture-pane", "-p", "-t", name], check=True, capture_output=True,
                                   text=True).stdout
            if re.search(r"offloads? over the last", shown):
                break
            assert time.monotonic() < deadline, f"no whole frame captured within {TIMEOUT} s: {shown}"
        (tmp_path / "screen.txt").write_text(shown)
        assert f"sim {sim} · aot1" in shown and re.search(r"\d+\.\d ticks/s", shown), shown
        for node in load_scenario("aot1").nodes:
            assert any(line.strip().startswith(node.id + " ") and "/" in line for line in shown.splitlines()), shown
        assert "█" in shown or "░" in shown
        subprocess.run([*tmux, "send-keys", "-t", name, "C-c"], check=True)
        wait_for(b"monitor-exit=0")
        assert f"monitor: detached from {sim}".encode() in stream and b"Traceback" not in stream
    finally:
        subprocess.run([*tmux, "kill-server"], check=False)
