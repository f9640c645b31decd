"""The bundled scenarios, the Ether importer and the generators."""

from __future__ import annotations

import collections
import json

import pytest

from orchestrator.scenario import load_scenario
from tests.conftest import ROOT, run_summary, write_scenario
from topologies.ether import load_ether
from topologies.generators import GENERATORS

# The paper's AoT networks (docs/scenario.md): nodes, rpi3 / nuc / tx2 / server, controllers, task sources
AOT = {
    "aot1": (12, {"rpi3": 8, "nuc": 1, "tx2": 2, "server": 1}, 10, 8),
    "aot2": (19, {"rpi3": 12, "nuc": 2, "tx2": 4, "server": 1}, 15, 12),
    "aot3": (28, {"rpi3": 18, "nuc": 3, "tx2": 6, "server": 1}, 22, 18),
    "aot4": (31, {"rpi3": 18, "nuc": 4, "tx2": 8, "server": 1}, 23, 18),
}
FILES = {"aot1": "one_cluste_8rpi_manual.json", "aot2": "network_2_clusters.json",
         "aot3": "network_3_clusters.json", "aot4": "network_4_clusters.json"}


@pytest.mark.parametrize("name", sorted(AOT))
def test_aot_scenarios_match_the_design_table(name):
    nodes, types, controllers, sources = AOT[name]
    sc = load_scenario(ROOT / "topologies" / f"{name}.yaml")
    assert len(sc.nodes) == nodes
    assert dict(collections.Counter(n.profile for n in sc.nodes)) == types
    assert len(sc.controllers) == controllers
    assert len(sc.clients) == sources
    # wiring: every rpi3 and tx2 links to its cluster's nuc and to the server; the server links to all
    server = "server_0"
    assert set(sc.neighbours[server]) == {n.id for n in sc.nodes} - {server}
    for n in sc.nodes:
        if n.profile in ("rpi3", "tx2"):
            nbrs = sc.neighbours[n.id]
            assert len(nbrs) == 2 and server in nbrs
            assert sc.node[next(j for j in nbrs if j != server)].profile == "nuc"


@pytest.mark.parametrize("name", sorted(FILES))
def test_ether_importer_degrees_match_the_file(name):
    import json

    path = ROOT / "topologies" / "ether" / FILES[name]
    raw = json.loads(path.read_text())
    draft = load_ether(path, task_bytes=300 * 1024 * 1024)
    by_id = {str(v["id"]): k for k, v in raw["nodes"].items()}
    degree = collections.Counter()
    for link in draft.links:
        degree[link.a] += 1
        degree[link.b] += 1
    for node_id, nbrs in raw["links"]["neighbours"].items():
        assert degree[by_id[node_id]] == len(nbrs)
    assert collections.Counter(n.profile for n in draft.nodes) == collections.Counter(AOT[name][1])


def test_ether_hardware_mapping():
    draft = load_ether(ROOT / "topologies" / "ether" / FILES["aot1"], task_bytes=300 * 1024 * 1024)
    hw = {n.profile: n.hints for n in draft.nodes}
    # one core of cpu_milis * 1000 instructions/s; buffer = floor(memory / 300 MiB)
    assert hw["rpi3"] == {"cores": 1, "frequency": 4.0e6, "buffer": 3}
    assert hw["tx2"] == {"cores": 1, "frequency": 4.0e6, "buffer": 26}
    assert hw["nuc"] == {"cores": 1, "frequency": 3.2e7, "buffer": 54}
    assert hw["server"] == {"cores": 1, "frequency": 8.8e7, "buffer": 597}


# Every Ether file shipped (topologies/ether/README.md): its node count, and how many of its devices are
# controllers and task sources (from their profile, or from their type label when the name is no profile).
SBC_SETS = {"sbc_rpi3": "3_type", "sbc_rpi4": "4_type", "sbc_rpi5_6G": "5_6G_type", "sbc_rpi5_8G": "5_8G_type",
            "sbc_heterogeneous": "heterogeneous_type"}
ETHER_FILES = {
    **{FILES[name]: (AOT[name][0], AOT[name][2], AOT[name][3]) for name in FILES},
    **{f"{folder}/network_{c}_clusters_{suffix}.json": counts for folder, suffix in SBC_SETS.items()
       for c, counts in zip((1, 2, 3, 4), ((8, 6, 4), (23, 19, 16), (32, 26, 22), (45, 37, 32)), strict=True)},
    # every device is a nuc (built in) or carries a type label with a controller; the sbc-labelled are sources
    **{f"artificial_networks/network_{shape}{n}.json": (n, n, n - 5) for shape in ("fully-connected", "grid",
                                                                                   "random", "ring")
       for n in (10, 15, 20, 25)},
    # here the rpi4 devices carry a NUC's labels (type sffc): hubs, not sources
    **{f"artificial_networks/network_bridged-clusters{n}.json": (n, n, sources)
       for n, sources in ((10, 3), (15, 7), (20, 10), (25, 13))},
}


def test_every_shipped_ether_file_is_counted():
    folder = ROOT / "topologies" / "ether"
    shipped = {str(p.relative_to(folder)) for p in folder.rglob("*.json")}
    assert shipped == set(ETHER_FILES)


@pytest.mark.parametrize("path", sorted(ETHER_FILES))
def test_every_ether_file_imports_with_its_node_count(path):
    nodes, controllers, sources = ETHER_FILES[path]
    raw = json.loads((ROOT / "topologies" / "ether" / path).read_text())
    sc = load_scenario({"topology": {"ether": f"ether/{path}"}})
    assert len(sc.nodes) == len(raw["nodes"]) == nodes
    assert (len(sc.controllers), len(sc.clients)) == (controllers, sources)
    # one core of cpu_milis * 1000 cycles/s each, whatever the device
    assert [n.frequency for n in sc.nodes] == [v["capacity"]["cpu_milis"] * 1000.0 for v in raw["nodes"].values()]


def test_a_device_without_a_profile_plays_the_part_of_its_type():
    sc = load_scenario({"topology": {"ether": "ether/sbc_rpi4/network_1_clusters_4_type.json"}})
    rpi4 = sc.node["rpi4_0"]  # an sbc, 7200 millicores, 6 GiB: like an rpi3, a sensing node with a controller
    assert (rpi4.profile, rpi4.tier, rpi4.roles) == ("rpi4", 0, ("worker", "client", "controller"))
    assert (rpi4.frequency, rpi4.buffer) == (7.2e6, 20)  # ⌊6 GiB / 300 MiB⌋
    # a scenario profile of that name refines what the type implies
    mine = load_scenario({"profiles": {"rpi4": {"client": False, "buffer": 5}},
                          "topology": {"ether": "ether/sbc_rpi4/network_1_clusters_4_type.json",
                                       "nodes": [{"id": "nuc_0", "client": True}]}})
    assert (mine.node["rpi4_0"].roles, mine.node["rpi4_0"].buffer) == (("worker", "controller"), 5)


GENERATOR_CASES = {
    "ring": {"kind": "ring", "n": 6, "profile": "tier0"},
    "grid": {"kind": "grid", "rows": 3, "cols": 3, "profile": "tier0"},
    "random_geometric": {"kind": "random_geometric", "n": 12, "radius": 60, "profile": "tier0", "seed": 4},
    "fully_connected": {"kind": "fully_connected", "n": 5, "profile": "tier0"},
    "bridged_clusters": {"kind": "bridged_clusters", "clusters": 3, "size": 4, "profile": "tier0"},
    "n_tier": {"kind": "n_tier", "tiers": [6, 3, 1], "profiles": ["tier0", "tier1", "tier2"], "cloud": "tier2"},
}


def test_every_generator_is_covered():
    assert set(GENERATOR_CASES) == set(GENERATORS)


@pytest.mark.parametrize("name", sorted(GENERATOR_CASES))
def test_generated_scenarios_run(tmp_path, name):
    sc = load_scenario(write_scenario(tmp_path, {"topology": {"generator": GENERATOR_CASES[name]},
                                                 "simulation": {"steps": 200}}))
    assert len(sc.nodes) >= 5
    summary = run_summary(sc, policy="least_queue")
    assert summary["totals"]["generated"] > 0


def test_generator_shapes(tmp_path):
    def build(gen):
        return load_scenario(write_scenario(tmp_path, {"topology": {"generator": gen}}))

    ring = build(GENERATOR_CASES["ring"])
    assert all(len(v) == 2 for v in ring.neighbours.values())
    grid = build(GENERATOR_CASES["grid"])
    assert sorted(len(v) for v in grid.neighbours.values()) == [2, 2, 2, 2, 3, 3, 3, 3, 4]
    full = build(GENERATOR_CASES["fully_connected"])
    assert all(len(v) == 4 for v in full.neighbours.values())
    tiers = build(GENERATOR_CASES["n_tier"])
    assert collections.Counter(n.tier for n in tiers.nodes) == {0: 6, 1: 3, 2: 2}
    clusters = build(GENERATOR_CASES["bridged_clusters"])
    assert clusters.undirected_links == 3 * 6 + 2
