"""``extends``: a scenario that is another one with some keys changed."""

from __future__ import annotations

import shutil

import pytest
import yaml

from orchestrator.cli import main
from orchestrator.scenario import ScenarioError, load_scenario
from topologies import bundled_file


def write(path, data):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_mappings_merge_key_by_key_and_everything_else_replaces(tmp_path):
    base = load_scenario("aot3_urgent")
    child = load_scenario(write(tmp_path / "bigger.yaml", {
        "extends": "aot3_urgent", "workload": {"arrival": {"rate": 0.05}},
        "topology": {"ether": "ether/network_4_clusters.json"}}))
    assert child.name == "bigger"  # a name is a file's own, never inherited
    assert len(child.nodes) == 31 and len(base.nodes) == 28
    assert child.workload.arrival.rate == 0.05 and child.workload.arrival.kind == base.workload.arrival.kind
    assert child.workload.task_types == base.workload.task_types  # inherited whole
    assert (child.dt, child.episode_ticks, child.max_hops) == (base.dt, base.episode_ticks, base.max_hops)

    one = load_scenario(write(tmp_path / "alerts.yaml", {
        "extends": "aot3_urgent", "workload": {"tasks": [{"name": "alert", "instructions": 2e8,
                                                          "input_bytes": 2e6, "output_bytes": 2e5,
                                                          "deadline": 15.0}]}}))
    assert [t.name for t in one.workload.task_types] == ["alert"]  # a list replaces, it does not append


def test_an_unchanged_extension_is_the_same_scenario(tmp_path):
    same = load_scenario(write(tmp_path / "same.yaml", {"name": "aot3_wired", "extends": "aot3_wired"}))
    assert same.digest() == load_scenario("aot3_wired").digest()


def test_chains_and_files_named_next_to_each_base(tmp_path):
    """A base in another folder finds the files it names next to itself; its own base, in turn, too."""
    (tmp_path / "lab").mkdir()
    shutil.copy(bundled_file("ether/network_2_clusters.json"), tmp_path / "lab" / "net.json")
    write(tmp_path / "lab" / "base.yaml", {"extends": "aot3_compute", "topology": {"ether": "net.json"}})
    write(tmp_path / "lab" / "middle.yaml", {"extends": "base.yaml", "workload": {"arrival": {"rate": 0.02}}})
    top = load_scenario(write(tmp_path / "runs" / "top.yaml", {"extends": "../lab/middle.yaml"}))
    assert len(top.nodes) == 19 and top.workload.arrival.rate == 0.02
    assert top.workload.task_types == load_scenario("aot3_compute").workload.task_types


def test_a_dict_may_extend_a_bundled_scenario():
    sc = load_scenario({"extends": "aot2", "simulation": {"steps": 50}}, name_hint="short")
    assert sc.name == "short" and sc.episode_ticks == 50 and len(sc.nodes) == 19


@pytest.mark.parametrize(("extends", "expected"), [
    (3, "extends: expected a bundled scenario's name or the path of a scenario file, got 3"),
    ("", "extends: expected a bundled scenario's name or the path of a scenario file, got ''"),
    ("aot33", "extends: aot33: no such file or bundled scenario (did you mean 'aot3'?); bundled: aot1,"),
    ("lab/missing.yaml", "extends: lab/missing.yaml: file not found"),
])
def test_a_bad_base_is_one_line_naming_the_file(tmp_path, capsys, extends, expected):
    path = write(tmp_path / "child.yaml", {"extends": extends})
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"{path}: {expected}") and len(err.splitlines()) == 1, err


def test_a_cycle_is_refused(tmp_path):
    write(tmp_path / "a.yaml", {"extends": "b.yaml"})
    write(tmp_path / "b.yaml", {"extends": "a.yaml"})
    with pytest.raises(ScenarioError) as e:
        load_scenario(tmp_path / "a.yaml")
    assert str(e.value).endswith("extends: 'a.yaml' extends itself (a.yaml -> b.yaml -> a.yaml)"), str(e.value)


def test_a_chain_too_deep_is_refused(tmp_path):
    for i in range(40):
        write(tmp_path / f"s{i}.yaml", {"extends": f"s{i + 1}.yaml"})
    write(tmp_path / "s40.yaml", {"extends": "aot1"})
    with pytest.raises(ScenarioError) as e:
        load_scenario(tmp_path / "s0.yaml")
    assert str(e.value).endswith("extends: more than 16 scenarios deep"), str(e.value)
    assert load_scenario(tmp_path / "s30.yaml").name == "s30"  # ten deep is fine


def test_an_error_in_an_inherited_key_names_the_extending_file(tmp_path, capsys):
    write(tmp_path / "base.yaml", {"extends": "aot2", "simulation": {"steps": "many"}})
    path = write(tmp_path / "child.yaml", {"extends": "base.yaml"})
    assert main(["validate", str(path)]) == 2
    assert capsys.readouterr().err.strip().startswith(f"{path}: simulation.steps: ")
