"""Numbers on the command line are checked like the scenario's YAML: one clear error line, exit status 2."""

from __future__ import annotations

import argparse
import json

import pytest

from node_runtime.runtime import remote
from orchestrator.cli import main

CASES = [
    (["launch", "aot1", "--steps", "-5"], "argument --steps: expected an integer from 1 to 2147483648 (got '-5')"),
    (["launch", "aot1", "--steps", "0"], "argument --steps: expected an integer from 1 to 2147483648 (got '0')"),
    (["launch", "aot1", "--steps", "2.5"], "argument --steps: expected an integer from 1 to 2147483648 (got '2.5')"),
    # an episode is at most 2^31 ticks (node_runtime.model.spec): past it a run went on for ever
    (["launch", "aot1", "--steps", str(10**22)],
     "argument --steps: expected an integer from 1 to 2147483648 (got '10000000000000000000000')"),
    (["launch", "aot1", "--tick-rate", "-5"], "argument --tick-rate: expected a number > 0 (got '-5')"),
    (["launch", "aot1", "--timeout", "0"], "argument --timeout: expected a number > 0 and <= 1e+06 (got '0')"),
    (["launch", "aot1", "--timeout", "inf"], "argument --timeout: expected a number > 0 and <= 1e+06 (got 'inf')"),
    # past a million seconds Zenoh's lease in milliseconds overflowed in every node process
    (["launch", "aot1", "--timeout", "1e308"], "argument --timeout: expected a number > 0 and <= 1e+06 (got '1e308')"),
    (["launch", "aot1", "--episodes", "-1"], "argument --episodes: expected an integer >= 0 (got '-1')"),
    (["launch", "aot1", "--seed", "-3"],
     "argument --seed: expected an integer from 0 to 4611686018427387903 (got '-3')"),
    (["launch", "aot1", "--seed", str(2**70)],
     "argument --seed: expected an integer from 0 to 4611686018427387903 (got '1180591620717411303424')"),
    (["bench", "--ticks", "0"], "argument --ticks: expected an integer >= 1 (got '0')"),
    (["trace", "alibaba", "x.csv", "--scenario", "aot2", "--out", "t.csv", "--frequency", "-1"],
     "argument --frequency: expected a number > 0 (got '-1')"),
    (["launch", "aot1", "--sim-id", "a/b"], "argument --sim-id: expected letters, digits, '_', '.' or '-' (got 'a/b')"),
    (["launch", "aot1", "--connect", "localhost"],
     "argument --connect: expected an endpoint such as tcp/10.0.0.1:7447 (got 'localhost')"),
    (["monitor", "--sim", "a/b"], "argument --sim: expected letters, digits, '_', '.' or '-' (got 'a/b')"),
]


@pytest.mark.parametrize(("argv", "expected"), CASES, ids=[" ".join(c[0][2:]) or c[0][0] for c in CASES])
def test_bad_numbers_are_rejected_with_one_line(argv, expected, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].endswith(f"error: {expected}")


def test_good_numbers_run(tmp_path, capsys):
    assert main(["launch", "aot1", "--transport", "inproc", "--steps", "3", "--tick-rate", "1000", "-q",
                 "--out", str(tmp_path)]) == 0
    assert (tmp_path / "summary.json").exists()


@pytest.mark.parametrize(("option", "expected"), [
    (["--sim", "a/b"], "argument --sim: expected letters, digits, '_', '.' or '-' (got 'a/b')"),
    (["--timeout", "-1"], "argument --timeout: expected a number > 0 and <= 1e+06 (got '-1')"),
])
def test_zenohedge_node_checks_the_same_options_the_same_way(capsys, option, expected):
    args = {"--connect": "tcp/10.0.0.1:7447", "--sim": "lab", "--group": "g"}
    args.update(dict([option]))
    with pytest.raises(SystemExit) as exc:
        remote.main([part for pair in args.items() for part in pair])
    assert exc.value.code == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == f"zenohedge-node: error: {expected}"


def test_several_episodes_each_get_their_folder(tmp_path):
    assert main(["launch", "aot1", "--transport", "inproc", "--steps", "3", "--episodes", "2", "-q",
                 "--out", str(tmp_path)]) == 0
    assert all((tmp_path / f"episode-{i}" / "summary.json").exists() for i in (0, 1))


@pytest.mark.parametrize("text", ["groups:0", "groups", "groups:x", "per-process", "groups:-2"])
def test_a_bad_layout_is_one_line(text):
    from orchestrator.arguments import layout_name

    with pytest.raises(argparse.ArgumentTypeError, match="expected per-role, per-node, single or groups:K"):
        layout_name(text)


def test_groups_split_the_nodes_in_contiguous_blocks():
    from node_runtime.runtime.layout import ProcessLayout
    from orchestrator.scenario import load_scenario

    plan = ProcessLayout(load_scenario("aot1"), "groups:5")  # 12 nodes
    assert plan.procs == tuple(f"group-{i}" for i in range(5))
    sizes = [len({r.partition(":")[2] for r in plan.roles_of[p]}) for p in plan.procs]
    assert sizes == [3, 2, 3, 2, 2] and sum(sizes) == 12
    assert len(ProcessLayout(load_scenario("aot1"), "groups:50").procs) == 12  # never more groups than nodes


@pytest.mark.parametrize("case", ["a file", "under a file", "summary.json is a directory"])
def test_an_output_directory_that_cannot_be_written_is_one_line_before_any_process_starts(tmp_path, capsys, case):
    """It used to be a FileExistsError or PermissionError traceback after the node processes had started;
    the incomplete summary.json written before they start is the check that the directory takes files."""
    taken = tmp_path / "a-file"
    taken.write_text("")
    out, bad, why = {"a file": (taken, taken, "File exists"),
                     "under a file": (taken / "run", taken / "run", "Not a directory"),
                     "summary.json is a directory": (tmp_path / "run", tmp_path / "run" / "summary.json",
                                                     "Is a directory")}[case]
    if case == "summary.json is a directory":
        bad.mkdir(parents=True)
    before = sorted(tmp_path.rglob("*"))
    assert main(["launch", "aot1", "--steps", "3", "-q", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"orchestrator: --out {bad}: cannot write the results there: {why}"
    assert sorted(tmp_path.rglob("*")) == before  # nothing left behind


def test_a_launch_that_fails_before_its_episode_leaves_no_directory(tmp_path, capsys, monkeypatch):
    """The incomplete summary.json written before the start goes again with the directories made for it."""
    from orchestrator import cli
    from orchestrator.session import RouterUnavailable

    def taken(*args, **kwargs):
        assert json.loads((out / "summary.json").read_text())["incomplete"]["last_tick"] is None  # written first
        raise RouterUnavailable("--listen 127.0.0.1:7447: the port is taken")

    out = tmp_path / "a" / "b"
    monkeypatch.setattr(cli.Simulation, "open", taken)
    assert main(["launch", "aot1", "--steps", "3", "-q", "--out", str(out)]) == 2
    assert capsys.readouterr().err.strip() == "orchestrator: --listen 127.0.0.1:7447: the port is taken"
    assert list(tmp_path.iterdir()) == []


def test_steps_past_the_longest_episode_are_refused_with_the_decision_interval(tmp_path, capsys):
    path = tmp_path / "s.yaml"
    path.write_text("topology: {nodes: [{id: a, client: true, controller: true}, {id: b}], links: [[a, b]]}\n"
                    "simulation: {decision_interval: 4}\n")
    assert main(["launch", str(path), "--transport", "inproc", "--steps", str(2**30), "-q",
                 "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.strip() == (
        f"orchestrator: --steps {2**30}: expected at most 2^31 (2147483648) ticks an episode, but {2**30} steps of "
        "4 tick(s) are 4294967296 (decision_interval 4)")
    assert not (tmp_path / "out").exists()


def test_no_episodes_without_serve_is_refused(capsys):
    assert main(["launch", "aot1", "--transport", "inproc", "--episodes", "0", "-q"]) == 2
    assert capsys.readouterr().err.strip() == (
        "orchestrator: --episodes 0 runs no episode: it is for --serve, which then only serves")


def test_launch_takes_a_policy_of_your_own_by_import_path(tmp_path, monkeypatch, capsys):
    """--policy names a built-in or a Policy subclass (module:Class); anything else fails before any process."""
    (tmp_path / "mypolicies.py").write_text(
        "from node_runtime.model.policies import Policy\n\nclass Last(Policy):\n    name = 'last'\n\n"
        "    def choose(self, obs, task, valid, extra):\n        return valid[-1]\n\n\nVALUE = 3\n")
    monkeypatch.chdir(tmp_path)
    assert main(["launch", "aot1", "--transport", "inproc", "--steps", "30", "--policy", "mypolicies:Last",
                 "--out", "run", "--json"]) == 0
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["policy"] == "mypolicies:Last" and summary["totals"]["offloaded"] > 0
    for policy, error in (("lowest_queue", "expected one of drift_plus_penalty, greedy, greedy_backlog, least_queue, "
                                           "local, local_first, random, round_robin, threshold or an import path "
                                           "'module:Class' (got 'lowest_queue')"),
                          ("mypolicies:VALUE", "mypolicies:VALUE is not a subclass of "
                                               "node_runtime.model.policies.Policy")):
        with pytest.raises(SystemExit) as e:
            main(["launch", "aot1", "--policy", policy])
        assert e.value.code == 2
        assert capsys.readouterr().err.strip().endswith(f"argument --policy: {error}")


def test_a_bare_orchestrator_prints_the_help_and_exits_0(capsys):
    assert main([]) == 0
    out, err = capsys.readouterr()
    assert out.startswith("usage: orchestrator") and "launch" in out and "validate" in out and err == ""


@pytest.mark.parametrize("command", [[], ["launch"], ["validate"], ["topology"]])
def test_the_help_names_every_bundled_scenario(command, capsys):
    from topologies import bundled_scenarios

    with pytest.raises(SystemExit) as exc:
        main([*command, "--help"])
    assert exc.value.code == 0
    words = set(capsys.readouterr().out.replace(",", " ").replace(".", " ").split())
    names = bundled_scenarios()
    assert len(names) >= 31 and "examples/minimal" in names
    assert not set(names) - words


@pytest.mark.parametrize("listen", ["0.0.0.0:7447", "[::]:7447", "10.0.0.1:7447", "myhost:7447"])
def test_listening_beyond_this_host_without_security_needs_insecure(listen, tmp_path, capsys):
    """It started silently, plain TCP for anyone who reaches the port; now one line and nothing started."""
    out = tmp_path / "out"
    assert main(["launch", "aot1", "--listen", listen, "--serve", "-q", "--out", str(out)]) == 2
    assert capsys.readouterr().err.strip() == (
        f"orchestrator: --listen {listen}: without --security anyone who reaches this host can drive the simulation "
        "and pose as its processes; add --security DIR (deploy/README.md), or --insecure on a network you trust")
    assert not out.exists()


def test_loopback_needs_neither_security_nor_insecure():
    from orchestrator.serve import is_loopback, reachable

    assert is_loopback("127.0.0.1") and is_loopback("[::1]") and is_loopback("localhost") and is_loopback("127.3.2.1")
    assert not is_loopback("0.0.0.0") and not is_loopback("::") and not is_loopback("192.168.1.4")
    assert reachable("tcp/127.0.0.1:7447") == ["tcp/127.0.0.1:7447"]
    assert reachable("tls/10.0.0.1:7447") == ["tls/10.0.0.1:7447"]
    assert reachable("tcp/0.0.0.0:7447")[-1] == "tcp/127.0.0.1:7447"
    assert reachable("tcp/[::]:7447")[-1] in ("tcp/[::1]:7447", "tcp/[::]:7447")  # [::] where IPv6 is off
