"""The nemesis suite: faults injected into real runs, each ending in results bit-identical to an undisturbed run
of the same seed (tests/golden.py's digests of summary.json's model part, ticks.csv and nodes.csv), or in a
failure that names the component at fault and keeps every row measured until then, once.

The faults: SIGSTOP and SIGCONT of each kind of process (a worker, a client, a controller, the orchestrator, a
host's ``zenohedge-node``, a process on a host), shorter and longer than ``--timeout``; a partition of a host,
healed and not; loss, delay and reordering on a host's link (netem); SIGKILL of a process on a host and of a
host. Hosts are network namespaces (deploy/netns.sh, root only). The nemesis is timed on the clock (a monitor
sees tick N), never on the time; only how long a fault lasts is a time. docs/security.md, "Faults we inject
and what holds", lists the outcomes.
"""

from __future__ import annotations

import functools
import re
import subprocess
import time
from pathlib import Path

import psutil
import pytest

from tests import golden
from tests.conftest import check_outputs, cut, wire, write_scenario
from tests.launcher import TIMEOUT, Launch, TickWatch, assert_all_gone, assert_host_empty, paused_run, spread

pytestmark = pytest.mark.zenoh

# Five nodes: a is the client and controller of the others' tasks; b, c, d are clients too, so that every
# process has work nearly every tick and the clock waits for whichever is stopped
SCENARIO = {"simulation": {"steps": 100000},
            "topology": {"nodes": [{"id": "a", "client": True, "controller": True}, {"id": "b", "client": True},
                                   {"id": "c", "client": True}, {"id": "d", "client": True}, {"id": "e"}],
                         "links": [["a", "b"], ["a", "c"], ["a", "d"], ["b", "c"], ["d", "e"], ["c", "e"]]},
            "workload": {"arrival": {"rate": 0.5}}}
NODES = 5
PLACEMENT = {"h1": ["b", "c"], "h2": ["d", "e"]}  # node a stays with the orchestrator
SEED, POLICY = 3, "random"
AT = 30  # the tick after which the nemesis strikes
SHORT_S = 1.5  # a pause or partition well within the --timeout of the runs that must not notice it
LONG_TIMEOUT = 10.0  # --timeout of those runs
SHORT_TIMEOUT = 2.0  # --timeout of the runs that must fail


@pytest.fixture(scope="module")
def scenario(tmp_path_factory: pytest.TempPathFactory) -> str:
    return str(write_scenario(tmp_path_factory.mktemp("nemesis"), SCENARIO, "nemesis.yaml"))


@functools.cache
def undisturbed(scenario: str, steps: int) -> dict[str, str]:
    """The digests of the run in one process: what every disturbed run that completes must give."""
    return {k: v for k, v in golden.run_case(golden.Case(scenario, steps, SEED, POLICY)).items() if k != "totals"}


def launch(scenario: str, out: Path, steps: int, timeout: float) -> Launch:
    return Launch(scenario, "--transport", "zenoh", "--steps", str(steps), "--seed", str(SEED), "--policy", POLICY,
                  "--timeout", str(timeout), "--out", str(out))


def spread_run(scenario: str, out: Path, steps: int, timeout: float) -> tuple[Launch, list]:
    return spread(out, scenario, PLACEMENT, "--steps", str(steps), "--seed", str(SEED), "--policy", POLICY,
                  "--timeout", str(timeout), sim="nemesis")


def strike(run: Launch, victims: dict[str, psutil.Process], seconds: float) -> None:
    """SIGSTOP each victim in turn, the k-th once the clock has done tick k * AT, and SIGCONT it ``seconds``
    later. The clock must have stood still meanwhile (the victim was in its way), and the run must go on."""
    watch = TickWatch(run)
    try:
        for k, (name, victim) in enumerate(victims.items(), start=1):
            watch.wait(k * AT, run)
            stopped_at = time.monotonic()
            victim.suspend()
            try:
                time.sleep(seconds)  # the fault itself: how long the process stays stopped
            finally:
                resumed_at = time.monotonic()
                victim.resume()
            assert watch.ticks_between(stopped_at + seconds / 2, resumed_at) == [], f"the clock went on without {name}"
            assert run.proc.poll() is None, f"the run ended while {name} was stopped:\n{''.join(run.err)}"
    finally:
        watch.close()


def reach(run: Launch, tick: int) -> None:
    """Return once the clock has done ``tick``."""
    watch = TickWatch(run)
    try:
        watch.wait(tick, run)
    finally:
        watch.close()


def silent(error: str) -> list[str]:
    """The processes a "hung" error names."""
    found = re.search(r"tick \d+: (.+?) \(nodes ", error)
    assert found, error
    return found.group(1).split(", ")


def failed_with_partial_results(run: Launch, out: Path, code: int = 1) -> str:
    """The run's exit status is ``code``; its outputs say it is incomplete and hold every tick done, once. Returns
    the error line."""
    assert run.finish(TIMEOUT) == code, "".join(run.err)
    errors = [line for line in run.err if line.startswith("error:")]
    assert errors, "".join(run.err[-5:])
    summary = check_outputs(out, NODES)
    assert summary["ticks"] > AT and "incomplete" in summary, summary.get("incomplete")
    return errors[0]


# ----- one host: each kind of process, stopped -----

LOCAL = {"worker": "zw-b", "client": "zc-a", "controller": "zk-a"}  # the default layout: one process per role


def test_pauses_within_the_timeout_change_nothing(tmp_path, scenario):
    """A worker, a client, a controller and the orchestrator (its router with it) stopped in turn, each for
    SHORT_S, in one run."""
    steps = 600
    run = launch(scenario, tmp_path, steps, LONG_TIMEOUT)
    run.wait_for("processes ready")
    strike(run, {**{kind: run.node(name) for kind, name in LOCAL.items()},
                 "orchestrator": psutil.Process(run.proc.pid)}, SHORT_S)
    assert run.finish(TIMEOUT) == 0, "".join(run.err)
    assert golden.outputs(tmp_path) == undisturbed(scenario, steps)


@pytest.mark.parametrize("kind", LOCAL)
def test_a_pause_past_the_timeout_names_the_process(tmp_path, scenario, kind):
    run = launch(scenario, tmp_path, 100000, SHORT_TIMEOUT)
    run.wait_for("processes ready")
    children = run.descendants()
    reach(run, AT)
    _, _, error = paused_run(run, run.node(LOCAL[kind]), TIMEOUT)
    proc = f"{kind}-{LOCAL[kind][3:]}"
    assert silent(error) == [proc] and "hung" in error and f"{proc} stopped by a signal" in error, error
    failed_with_partial_results(run, tmp_path)
    assert_all_gone(children)


def test_a_killed_process_is_named_and_nothing_is_left(tmp_path, scenario):
    run = launch(scenario, tmp_path, 100000, LONG_TIMEOUT)
    run.wait_for("processes ready")
    children = run.descendants()
    reach(run, AT)
    run.node("zw-b").kill()
    error = failed_with_partial_results(run, tmp_path)
    assert "process worker-b (node b) exited unexpectedly (killed by SIGKILL)" in error, error
    assert_all_gone(children)


@pytest.mark.slow
def test_an_orchestrator_stopped_past_the_lease_names_itself(tmp_path, scenario):
    """--timeout 1: its processes' Zenoh lease is 6 s; stopped 9 s, it finds them gone and says it stood still."""
    run = launch(scenario, tmp_path, 100000, 1)
    run.wait_for("processes ready")
    children = run.descendants()
    reach(run, AT)
    orchestrator = psutil.Process(run.proc.pid)
    orchestrator.suspend()
    try:
        time.sleep(9)  # the stall itself
    finally:
        orchestrator.resume()
    error = failed_with_partial_results(run, tmp_path)
    assert "the orchestrator itself stood still" in error and "none of them failed" in error, error
    assert_all_gone(children)


# ----- two hosts (network namespaces), each running a group under zenohedge-node -----

def named_only_group(error: str, group: str) -> None:
    """The error names ``group`` and none of the processes of another group or of the orchestrator's host."""
    assert f"group {group}" in error, error
    innocent = [f"node-{n}" for g, nodes in PLACEMENT.items() if g != group for n in nodes] + ["node-a"]
    assert not [p for p in innocent if p in error], error


def test_pauses_of_a_host_within_the_timeout_change_nothing(tmp_path, scenario, hosts):
    """Host 1's zenohedge-node (the router and the aggregator of its processes), then one of its processes,
    stopped in turn for SHORT_S, in one run."""
    steps = 4 * AT
    run, groups = spread_run(scenario, tmp_path, steps, LONG_TIMEOUT)
    host = psutil.Process(groups[0].pid)
    process = next(p for p in host.children(recursive=True) if p.name() == "zn-b")
    strike(run, {"host h1": host, "node-b on host h1": process}, SHORT_S)
    assert run.finish(TIMEOUT) == 0, "".join(run.err)
    assert [g.wait(TIMEOUT) for g in groups] == [0, 0], [g.stderr.read() for g in groups]
    assert golden.outputs(tmp_path) == undisturbed(scenario, steps)


def test_a_host_paused_past_the_timeout_is_named(tmp_path, scenario, hosts):
    run, groups = spread_run(scenario, tmp_path, 100000, SHORT_TIMEOUT)
    reach(run, AT)
    _, _, error = paused_run(run, psutil.Process(groups[0].pid), TIMEOUT)
    assert "the host of group h1 hung or was cut off: nothing came from it for" in error, error
    named_only_group(error, "h1")
    failed_with_partial_results(run, tmp_path)
    assert [g.wait(TIMEOUT) for g in groups] == [0, 0], [g.stderr.read() for g in groups]  # resumed, told it is over
    for ns in hosts:
        assert_host_empty(ns)


def test_a_process_on_a_host_paused_past_the_timeout_is_named(tmp_path, scenario, hosts):
    """Its host forwards the reports of the others: only the stopped process is named."""
    run, groups = spread_run(scenario, tmp_path, 100000, SHORT_TIMEOUT)
    victim = next(p for p in psutil.Process(groups[0].pid).children(recursive=True) if p.name() == "zn-b")
    reach(run, AT)
    _, _, error = paused_run(run, victim, TIMEOUT)
    assert silent(error) == ["node-b"] and "hung" in error and "the host of" not in error, error
    failed_with_partial_results(run, tmp_path)


def test_a_partition_healed_within_the_timeout_changes_nothing(tmp_path, scenario, hosts):
    steps = 4 * AT
    run, groups = spread_run(scenario, tmp_path, steps, LONG_TIMEOUT)
    watch = TickWatch(run)
    try:
        watch.wait(AT, run)
        cut_at = time.monotonic()
        cut(1, down=True)
        try:
            time.sleep(SHORT_S)  # the partition itself
        finally:
            healed_at = time.monotonic()
            cut(1, down=False)
        assert watch.ticks_between(cut_at + SHORT_S / 2, healed_at) == [], "the clock went on without host 1"
    finally:
        watch.close()
    assert run.finish(TIMEOUT) == 0, "".join(run.err)
    assert [g.wait(TIMEOUT) for g in groups] == [0, 0], [g.stderr.read() for g in groups]
    assert golden.outputs(tmp_path) == undisturbed(scenario, steps)


@pytest.mark.slow
def test_a_partition_past_the_timeout_names_the_host_and_its_processes_leave(tmp_path, scenario, hosts):
    run, groups = spread_run(scenario, tmp_path, 100000, SHORT_TIMEOUT)
    children = run.descendants()
    reach(run, AT)
    cut(1, down=True)
    try:
        error = failed_with_partial_results(run, tmp_path)
        assert "the host of group h1 hung or was cut off: nothing came from it for" in error, error
        named_only_group(error, "h1")
        assert_all_gone(children)
        assert groups[1].wait(TIMEOUT) == 0, groups[1].stderr.read()  # told the run is over
        assert_host_empty("zedge-host1", timeout=TIMEOUT)  # cut off: they leave once the lease lapses
    finally:
        cut(1, down=False)


@pytest.mark.slow
def test_loss_delay_and_reordering_change_nothing(tmp_path, scenario, hosts):
    """From tick AT on, 5 % of the frames lost and the others delayed 20 ms ± 5 ms, each on its own (so they
    overtake each other), both ways on host 1's link: Zenoh's reliable channel over TCP delivers everything,
    in order; the clock waits."""
    steps = AT + 40
    with wire(1, loss=0.05, delay=0.02, jitter=0.005) as link:
        run, groups = spread_run(scenario, tmp_path, steps, LONG_TIMEOUT)
        watch = TickWatch(run)
        try:
            watch.wait(AT, run)
            struck_at = time.monotonic()
            link.strike()
            assert run.finish(TIMEOUT) == 0, "".join(run.err)
        finally:
            watch.close()
        assert watch.ticks_between(struck_at, time.monotonic()), "the run was over before the faults"
        assert [g.wait(TIMEOUT) for g in groups] == [0, 0], [g.stderr.read() for g in groups]
    assert link.counts["dropped"] > 0 and link.counts["reordered"] > 0, link.counts  # the faults were there
    assert golden.outputs(tmp_path) == undisturbed(scenario, steps)


def test_a_process_killed_on_a_host_is_named_and_nothing_is_left(tmp_path, scenario, hosts):
    run, groups = spread_run(scenario, tmp_path, 100000, LONG_TIMEOUT)
    children = run.descendants()
    remote = [p for g in groups for p in psutil.Process(g.pid).children(recursive=True)]
    reach(run, AT)
    next(p for p in remote if p.name() == "zn-b").kill()
    error = failed_with_partial_results(run, tmp_path)
    assert "process node-b (node b) on the host of group h1 died: its liveliness token vanished" in error, error
    assert_all_gone(children + remote)
    assert [g.wait(TIMEOUT) for g in groups] == [1, 0], [g.stderr.read() for g in groups]
    for ns in hosts:
        assert_host_empty(ns)


def test_a_host_killed_is_named_and_a_restart_does_not_rejoin(tmp_path, scenario, hosts):
    """SIGKILL of h1's zenohedge-node: its processes lose their router and leave; the run ends naming the
    group. Started again, it finds no simulation to join (there is no rejoining) and says so."""
    run, groups = spread_run(scenario, tmp_path, 100000, LONG_TIMEOUT)
    children = run.descendants()
    remote = [p for g in groups for p in psutil.Process(g.pid).children(recursive=True)]
    reach(run, AT)
    groups[0].kill()
    error = failed_with_partial_results(run, tmp_path)
    assert "the host of group h1 is gone: the liveliness tokens of all its 2 processes" in error, error
    named_only_group(error, "h1")
    assert_all_gone(children + remote)
    assert groups[1].wait(TIMEOUT) == 0, groups[1].stderr.read()
    for ns in hosts:
        assert_host_empty(ns)
    again = subprocess.run(groups[0].args, capture_output=True, text=True, timeout=TIMEOUT)
    assert again.returncode == 2 and "zenohedge-node: cannot connect to tcp/10.77.1.1:" in again.stderr, again.stderr
