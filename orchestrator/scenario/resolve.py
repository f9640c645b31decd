"""The second pass: from a structurally valid file to a resolved ``Scenario``.

It resolves references between nodes, links, failures and traces, applies profiles in order of
precedence, derives link rates, checks connectivity and roles, and imports user extensions once so
that a typo fails with its key path, not inside a node process.
"""

from __future__ import annotations

import csv
import difflib
import inspect
import math
from pathlib import Path
from typing import Any

import networkx as nx
from pydantic import ConfigDict, ValidationError, validate_call

from node_runtime.model.dag import Jobs
from node_runtime.model.messages import LONGEST_DEADLINE_TICKS, TaskSize
from node_runtime.model.mobility import RadioRange, Trace
from node_runtime.model.plugins import PluginError, extend_path, is_import_path, load
from node_runtime.model.positions import bounds, box_distance, link_rate
from node_runtime.model.radio import free_space_loss_db, log_distance_gain_db, shannon_rate
from node_runtime.model.registry import ROLE_KINDS
from node_runtime.model.role import Role
from node_runtime.model.spec import Hardware, LinkSpec, NodeSpec, Scenario, TaskType, TraceRow, Workload
from orchestrator.scenario.errors import ScenarioError, describe, error_path, key_path
from orchestrator.scenario.schema import (
    BUILTIN_PROFILES,
    NODE_DEFAULTS,
    REWARD_NAMES,
    ScenarioFile,
    WorkloadCfg,
    file_format,
)
from topologies import bundled_file
from topologies.alibaba import Conversion, TraceError
from topologies.alibaba_dag import read_dags
from topologies.draft import Draft, DraftLink, DraftNode
from topologies.ether import DEVICE_TYPES, EtherError, load_ether
from topologies.generators import GENERATORS, GeneratorError
from topologies.mobility import MobilityError, Samples, read_fcd, read_trace

# Tasks are objects of their own: a mean of a million per tick and source is far past what runs (and
# past it, numpy's Poisson draw fails outright near 1e19)
MAX_TASKS_PER_TICK = 1e6
FINITE = ConfigDict(allow_inf_nan=False)  # a generator's numbers, as the file's own (schema.Strict)


def resolve(data: dict[str, Any], base: Path, default_name: str, label: str,
            also: tuple[Path, ...] = ()) -> Scenario:
    """``base``: the scenario file's folder; ``also``: further folders to find the files it names in (those
    of the scenarios it extends)."""
    import_new_kinds(data, base, label)
    model = file_format(tuple(ROLE_KINDS))
    try:
        cfg = model.model_validate(data)
    except ValidationError as exc:
        raise ScenarioError([f"{label}: {error_path(e)}: {describe(e, model)}"
                             for e in exc.errors()]) from None
    return _Resolver(cfg, base, label, also).scenario(cfg.name or default_name)


def import_new_kinds(data: dict[str, Any], base: Path, label: str) -> None:
    """Import the classes that the top-level ``roles`` names for kinds this process does not know:
    a new kind's module registers it, and the file format then has its keys."""
    roles = data.get("roles")
    if not isinstance(roles, dict):
        return
    errors = []
    for kind, path in roles.items():
        if kind in ROLE_KINDS or not isinstance(path, str) or not is_import_path(path):
            continue  # a known kind's class is checked with the other extensions; the rest is the schema's
        importable_from(base)
        try:
            load(path, Role)
        except PluginError as exc:
            errors.append(f"{label}: roles.{kind}: {exc}")
            continue
        if kind not in ROLE_KINDS:
            hint = difflib.get_close_matches(str(kind), ROLE_KINDS, n=1)
            errors.append(f"{label}: roles.{kind}: unknown role kind " + (
                f"(did you mean '{hint[0]}'?)" if hint else
                f"{kind!r}: importing {path} did not register it (node_runtime.model.registry.register)"))
    if errors:
        raise ScenarioError(errors)


def importable_from(base: Path) -> None:
    """Modules next to the scenario file are importable (its directory joins sys.path, which node
    processes inherit)."""
    if base.is_dir():
        extend_path([str(base)])


class _Resolver:
    """The second pass: meaning, references and derived values."""

    def __init__(self, cfg: ScenarioFile, base: Path, label: str, also: tuple[Path, ...] = ()) -> None:
        self.cfg = cfg
        self.base = base
        self.also = also
        self.label = label
        self.errors: list[str] = []
        self.traces: dict[tuple[str, Path], Samples] = {}  # position files read, by (model, path)

    def error(self, path: str, message: str) -> None:
        self.errors.append(f"{self.label}: {path}: {message}")

    def fail_if_errors(self) -> None:
        if self.errors:
            raise ScenarioError(self.errors)

    def file(self, ref: str) -> Path:
        """A file named in the scenario: absolute, next to the scenario (or to a scenario it extends), or
        shipped with the package (so that any scenario can say ``ether: ether/network_2_clusters.json``)."""
        p = Path(ref)
        if p.is_absolute():
            return p
        found = next((folder / p for folder in (self.base, *self.also) if (folder / p).exists()), None)
        return found or bundled_file(ref) or self.base / p

    def scenario(self, name: str) -> Scenario:
        cfg = self.cfg
        tasks = tuple(cfg.workload.tasks)
        draft = self.draft(tasks)
        self.fail_if_errors()
        nodes = self.nodes(draft)
        self.fail_if_errors()
        radio = self.radio(nodes)
        self.fail_if_errors()
        links = self.links(draft, nodes, radio)
        self.fail_if_errors()
        self.check_graph(nodes, links)
        self.check_failures({n.id for n in nodes})
        workload = self.workload(tasks, nodes, links)
        self.fail_if_errors()
        self.check_extensions(nodes)
        self.fail_if_errors()
        return Scenario(
            **dict(cfg.simulation),
            name=name,
            nodes=tuple(nodes),
            links=tuple(links),
            workload=workload,
            failures=tuple(cfg.failures),
            kinds=tuple((name, kind.path) for name, kind in ROLE_KINDS.items() if any(n.has(name) for n in nodes)),
            source=self.label,
            radio=radio,
            extra={"description": cfg.description, "reward": cfg.reward or "", "observation": cfg.observation or ""},
        )

    # --- user extensions ---

    def check_extensions(self, nodes: list[NodeSpec]) -> None:
        """Import every extension once here, so that a typo fails with its key path, not in a node."""
        from node_runtime.model.policies import Policy
        from node_runtime.model.workload import TaskSource

        cfg = self.cfg
        checks: dict[tuple[str, str], tuple[type | None, bool]] = {}
        bases = {name: kind.base for name, kind in ROLE_KINDS.items()}
        for kind, base in bases.items():
            path = getattr(cfg.roles, kind)
            if path:
                checks[(f"roles.{kind}", path)] = (base, False)
        entries = [(f"profiles.{name}", p) for name, p in cfg.profiles.items()]
        entries += [(f"topology.nodes[{i}]", n) for i, n in enumerate(cfg.topology.nodes)]
        for where, entry in entries:  # profiles and nodes both take roles and a policy
            for kind, base in bases.items():
                path = getattr(entry.roles, kind) if entry.roles else None
                if path:
                    checks[(f"{where}.roles.{kind}", path)] = (base, False)
            if entry.policy and is_import_path(entry.policy):
                checks[(f"{where}.policy", entry.policy)] = (Policy, False)
        if is_import_path(cfg.simulation.policy):
            checks[("simulation.policy", cfg.simulation.policy)] = (Policy, False)
        if cfg.workload.source:
            checks[("workload.source", cfg.workload.source)] = (TaskSource, False)
        for i, task in enumerate(cfg.workload.tasks):
            if task.payload is not None:
                checks[(f"workload.tasks[{i}].payload.call", task.payload.call)] = (None, True)
        if cfg.reward and cfg.reward not in REWARD_NAMES:
            if is_import_path(cfg.reward):
                checks[("reward", cfg.reward)] = (None, True)
            else:
                self.error("reward", f"expected one of {', '.join(REWARD_NAMES)} or an import path "
                                     f"'module:function' (got {cfg.reward!r})")
        if checks or cfg.observation:
            importable_from(self.base)
        for (key, path), (base, callable_ok) in checks.items():
            try:
                load(path, base, callable_ok=callable_ok)
            except PluginError as exc:
                self.error(key, str(exc))
        if cfg.observation:
            try:
                builder = load(cfg.observation)
                if not (isinstance(builder, type) and callable(getattr(builder, "encode", None))
                        and callable(getattr(builder, "space", None))):
                    raise PluginError(f"{cfg.observation} is not an observation builder class (with space() and "
                                      "encode() methods; see env.observations.ObservationBuilder)")
            except PluginError as exc:
                self.error("observation", str(exc))

    # --- topology ---

    def draft(self, tasks: tuple[TaskType, ...]) -> Draft:
        topo = self.cfg.topology
        if topo.ether is not None:
            total_w = sum(t.weight for t in tasks)
            task_bytes = sum(t.weight * (t.input_bytes + t.output_bytes) for t in tasks) / total_w
            try:
                draft = load_ether(self.file(topo.ether), task_bytes, wired_rates=topo.link_rates == "ether",
                                   buffer_bytes=topo.buffer_bytes)
            except EtherError as exc:
                self.error("topology.ether", str(exc))
                return Draft([], [])
        elif topo.generator is not None:
            params = dict(topo.generator.model_extra or {})
            try:
                draft = validate_call(GENERATORS[topo.generator.kind], config=FINITE)(**params)
            except ValidationError as exc:
                for e in exc.errors():
                    arg = e["loc"][-1] if e["loc"] else ""
                    if e["type"] == "unexpected_keyword_argument":
                        names = [p for p in inspect.signature(GENERATORS[topo.generator.kind]).parameters]
                        self.error(f"topology.generator.{arg}", f"unknown parameter of {topo.generator.kind}; "
                                   f"expected one of: {', '.join(names)}")
                    elif e["type"] == "missing_argument":
                        self.error(f"topology.generator.{arg}", f"{topo.generator.kind} needs this parameter")
                    else:
                        self.error(f"topology.generator.{key_path(e['loc'])}", describe(e, type(self.cfg)))
                return Draft([], [])
            except GeneratorError as exc:
                self.error("topology.generator", str(exc))
                return Draft([], [])
        else:
            draft = Draft([], [])
        known = {n.id: i for i, n in enumerate(draft.nodes)}
        listed: set[str] = set()
        reported: set[str] = set()  # ids already in an error: no follow-on errors about them
        for i, node in enumerate(topo.nodes):  # explicit nodes: new ones, or overrides of imported ones
            if node.id in listed:
                self.error(f"topology.nodes[{i}].id", f"duplicate node id {node.id!r}")
                continue
            listed.add(node.id)
            if node.id in known:
                continue
            if draft.nodes and node.profile is None and topo.ether is not None:
                self.error(f"topology.nodes[{i}].id", f"no node {node.id!r} in the Ether file (to add a new "
                           "node, give it a profile)")
                reported.add(node.id)
                continue
            known[node.id] = len(draft.nodes)
            draft.nodes.append(DraftNode(node.id, node.profile or "", node.position))
        listed_links: dict[frozenset[str], int] = {}
        for i, link in enumerate(topo.links):
            key = frozenset(link.between)
            if key in listed_links:
                self.error(f"topology.links[{i}].between", f"duplicate link (also topology.links[{listed_links[key]}])")
                continue
            listed_links[key] = i
            draft.links.append(DraftLink(link.between[0], link.between[1], link.rate_bps))
            for end in link.between:
                if end not in known and end not in reported:
                    self.error(f"topology.links[{i}].between", f"unknown node {end!r}")
        return draft

    def nodes(self, draft: Draft) -> list[NodeSpec]:
        cfg = self.cfg
        explicit = {n.id: (i, n) for i, n in enumerate(cfg.topology.nodes)}
        out = []
        unknown_profiles: set[tuple[str, str]] = set()
        for node in draft.nodes:  # ids are unique here: the draft step rejected duplicates
            where = f"topology.nodes[{explicit[node.id][0]}]" if node.id in explicit else f"node {node.id!r}"
            override = explicit.get(node.id, (0, None))[1]
            profile_name = (override.profile if override and override.profile else None) or node.profile
            # Precedence, lowest first: defaults, built-in profile, what the topology source knows
            # about the device, the scenario's profile, the node's own entry.
            values: dict[str, Any] = dict(NODE_DEFAULTS)
            values.update({name: kind.default for name, kind in ROLE_KINDS.items()})
            values.update(tx_power_dbm=cfg.network.tx_power_dbm, idle_power_w=cfg.energy.idle_power_w,
                          kappa=cfg.energy.kappa, policy=cfg.simulation.policy, payload_hz=None)
            # an imported device whose profile is not defined plays the part its type implies
            device = node.device if profile_name == node.profile else {}
            if (profile_name and profile_name not in BUILTIN_PROFILES and profile_name not in cfg.profiles
                    and not device):
                # a generator's profile is reported once, not once per generated node
                generated = cfg.topology.generator is not None and not (override and override.profile)
                key = "topology.generator" if generated else f"{where}.profile"
                if (key, profile_name) not in unknown_profiles:
                    unknown_profiles.add((key, profile_name))
                    hint = difflib.get_close_matches(profile_name, [*BUILTIN_PROFILES, *cfg.profiles], n=1)
                    self.error(key, f"unknown profile {profile_name!r}"
                               + (f" (did you mean '{hint[0]}'?)" if hint else "")
                               + f"; define it under 'profiles' or use one of {', '.join(BUILTIN_PROFILES)}"
                               + (f" (an Ether device of type {', '.join(DEVICE_TYPES)} needs none)"
                                  if cfg.topology.ether and not override else ""))
                continue
            values.update(BUILTIN_PROFILES.get(profile_name, device))
            values.update(node.hints)
            if profile_name in cfg.profiles:
                values.update(cfg.profiles[profile_name].model_dump(exclude_none=True))
            roles = cfg.roles.model_dump(exclude_none=True)
            params: dict[str, Any] = {}
            profile = cfg.profiles.get(profile_name) if profile_name else None
            if profile is not None:
                roles.update(profile.roles.model_dump(exclude_none=True) if profile.roles else {})
                params.update(profile.params or {})
            values.pop("roles", None)
            values.pop("params", None)
            position = node.position
            if override is not None:
                values.update(override.model_dump(exclude_none=True,
                                                  exclude={"id", "profile", "position", "roles", "params"}))
                if override.roles is not None:
                    roles.update(override.roles.model_dump(exclude_none=True))
                params.update(override.params or {})
                if "position" in override.model_fields_set:
                    position = override.position
            mobility = self.mobility(node.id, where, position, override, profile_name)
            if isinstance(mobility, Trace):
                position = mobility.samples[0][1:]  # a trace says where the node starts
            kinds = tuple(name for name in ROLE_KINDS if values[name])
            for name in kinds:
                for need in ROLE_KINDS[name].needs:
                    if not values.get(need):
                        self.error(f"{where}.{name}", f"a {name} needs a {need} on its node ({need}: true)")
            try:
                impls = tuple((name, roles[name]) for name in ROLE_KINDS if roles.get(name))
                out.append(NodeSpec(
                    **{key: values[key] for key in Hardware.model_fields}, id=node.id,
                    position=(float(position[0]), float(position[1])), roles=kinds, policy=values["policy"],
                    profile=profile_name or "", impls=impls, params=tuple(sorted(params.items())),
                    mobility=mobility))
            except ValidationError as exc:  # the file's values are valid: hardware a topology source gave is not
                for e in exc.errors():
                    self.error(f"{where}.{key_path(e['loc'])}",
                               f"{describe(e, NodeSpec)}, as the topology source gives it")
        for name in cfg.profiles:
            if not any(n.profile == name for n in out) and name not in BUILTIN_PROFILES:
                self.error(f"profiles.{name}", "profile is not used by any node")
        if not draft.nodes:
            self.error("topology", "the topology has no nodes")
        return out

    def links(self, draft: Draft, nodes: list[NodeSpec], radio: RadioRange | None) -> list[LinkSpec]:
        net = self.cfg.network
        noise, ref_loss = self.noise_dbm(), self.ref_loss_db()
        pl = net.path_loss
        by_id = {n.id: n for n in nodes}
        moving = {n.id for n in nodes if n.mobility is not None}
        explicit = {frozenset(lk.between): (i, lk) for i, lk in enumerate(self.cfg.topology.links)}
        seen: set[frozenset[str]] = set()
        out = []
        for link in draft.links:
            key = frozenset((link.a, link.b))
            where = f"topology.links[{explicit[key][0]}]" if key in explicit else f"link {link.a}-{link.b}"
            if link.a == link.b:
                self.error(f"{where}.between", f"a node cannot link to itself ({link.a!r})")
                continue
            if key in seen:
                if key in explicit:
                    continue  # an explicit link overriding an imported one
                self.error(f"{where}.between", "duplicate link")
                continue
            seen.add(key)
            override = explicit.get(key, (0, None))[1]
            if key & moving:  # its links are every pair in range, added below
                if override is not None:
                    self.error(f"{where}.between", f"{sorted(key & moving)[0]!r} moves: its links follow its position "
                               "(every node within network.range_m); remove this link")
                continue
            rate = link.rate_bps if override is None or override.rate_bps is None else override.rate_bps
            loss = net.loss if override is None or override.loss is None else override.loss
            for src, dst in ((link.a, link.b), (link.b, link.a)):
                r = rate
                if r is None:
                    a, b = by_id[src], by_id[dst]
                    gain = override.gain_db if override is not None and override.gain_db is not None else \
                        log_distance_gain_db(math.dist(a.position, b.position), ref_loss, pl.ref_distance_m,
                                             pl.exponent)
                    r = shannon_rate(net.bandwidth_hz, a.tx_power_dbm, gain, noise)
                if not r > 0:  # nan too: e.g. an Ether file's NaN coordinates (Python's json reads them)
                    self.error(f"{where}", f"link {src}->{dst} has no capacity (rate {r:g} bit/s)")
                out.append(LinkSpec(src, dst, r, loss))
        if radio is not None:
            out.extend(self.moving_links(nodes, radio, seen))
        return out

    def moving_links(self, nodes: list[NodeSpec], radio: RadioRange, listed: set[frozenset[str]]) -> list[LinkSpec]:
        """A link between every two nodes, one of them moving, that can ever come within range (by where each
        can be: a point, its area or its trace's box), whatever the seed: the links a controller may act on.
        Each carries the rate it has at the edge of the range, the least it has while it exists."""
        out = []
        loss = self.cfg.network.loss
        for i, a in enumerate(nodes):
            for b in nodes[i + 1:]:
                if (a.mobility is None and b.mobility is None) or frozenset((a.id, b.id)) in listed:
                    continue
                if box_distance(bounds(a.mobility, a.position), bounds(b.mobility, b.position)) <= radio.range_m:
                    out.append(LinkSpec(a.id, b.id, link_rate(radio, a.tx_power_dbm, radio.range_m), loss))
                    out.append(LinkSpec(b.id, a.id, link_rate(radio, b.tx_power_dbm, radio.range_m), loss))
        return out

    def noise_dbm(self) -> float:
        net = self.cfg.network
        return net.noise_dbm if net.noise_dbm is not None else -174.0 + 10 * math.log10(net.bandwidth_hz)

    def ref_loss_db(self) -> float:
        pl = self.cfg.network.path_loss
        return pl.ref_loss_db if pl.frequency_hz is None else free_space_loss_db(pl.ref_distance_m, pl.frequency_hz)

    def radio(self, nodes: list[NodeSpec]) -> RadioRange | None:
        """The radio of moving nodes' links, when a node moves; a range with no moving node is a mistake."""
        net = self.cfg.network
        moving = [n for n in nodes if n.mobility is not None]
        if not moving:
            for key in ("range_m", "on_break"):
                if key in net.model_fields_set:
                    self.error(f"network.{key}", "no node moves: give a node or profile a 'mobility'")
            return None
        if net.range_m is None:
            self.error("network.range_m", f"node {moving[0].id!r} moves: expected the radio range of moving nodes' "
                       "links, in metres")
            return None
        pl = net.path_loss
        return RadioRange(range_m=net.range_m, on_break=net.on_break, bandwidth_hz=net.bandwidth_hz,
                          noise_dbm=self.noise_dbm(), ref_loss_db=self.ref_loss_db(),
                          ref_distance_m=pl.ref_distance_m, exponent=pl.exponent)

    def mobility(self, node: str, where: str, position: tuple[float, float], override: Any,
                 profile: str | None) -> Any:
        """The node's movement (its own entry's, else its profile's), with a trace or FCD file read into samples;
        None if it stays where it is."""
        cfg = self.cfg
        if override is not None and override.mobility is not None:
            model, key = override.mobility, f"{where}.mobility"
        elif profile in cfg.profiles and cfg.profiles[profile].mobility is not None:
            model, key = cfg.profiles[profile].mobility, f"profiles.{profile}.mobility"
        else:
            return None
        if model.model in ("trace", "fcd"):
            name = (model.node if model.model == "trace" else model.vehicle) or node
            path = self.file(model.file)
            if (model.model, path) not in self.traces:
                try:
                    self.traces[(model.model, path)] = (read_trace if model.model == "trace" else read_fcd)(path)
                except MobilityError as exc:
                    self.traces[(model.model, path)] = {}
                    self.error(f"{key}.file", str(exc))
                    return None
            samples = self.traces[(model.model, path)].get(name)
            if samples is None:
                if self.traces[(model.model, path)]:
                    what = "node" if model.model == "trace" else "vehicle"
                    self.error(f"{key}.file", f"{path} has no {what} {name!r} (node {node!r})")
                return None
            return Trace(samples=tuple(samples))
        if not model.area.contains(position):
            self.error(f"{key}.area", f"node {node!r} starts at {tuple(position)}, outside the area: expected its "
                       "position inside it")
        return model

    def check_graph(self, nodes: list[NodeSpec], links: list[LinkSpec]) -> None:
        g = nx.Graph()
        g.add_nodes_from(n.id for n in nodes)
        g.add_edges_from((lk.src, lk.dst) for lk in links)
        if len(nodes) > 1 and not nx.is_connected(g):
            parts = sorted((sorted(c) for c in nx.connected_components(g)), key=len)
            isolated = ", ".join(parts[0][:5]) + (" ..." if len(parts[0]) > 5 else "")
            self.error("topology", f"the network is disconnected ({len(parts)} parts; e.g. {{{isolated}}} "
                       "cannot reach the rest): add links")
        if not any(n.has("client") for n in nodes):
            self.error("topology", "no node is a task source: set 'client: true' on a node or profile")

    def check_failures(self, ids: set[str]) -> None:
        for i, f in enumerate(self.cfg.failures):
            if f.node not in ids:
                self.error(f"failures[{i}].node", f"unknown node {f.node!r}")

    def workload(self, tasks: tuple[TaskType, ...], nodes: list[NodeSpec], links: list[LinkSpec]) -> Workload:
        wl = self.cfg.workload
        by_id = {n.id: n for n in nodes}
        nbrs: dict[str, set[str]] = {n.id: set() for n in nodes}
        for lk in links:
            nbrs[lk.src].add(lk.dst)
        for c in wl.rates:
            if c not in by_id:
                self.error(f"workload.rates.{c}", f"unknown node {c!r}")
            elif not by_id[c].has("client"):
                self.error(f"workload.rates.{c}", f"node {c!r} is not a task source (client: false)")
        for c, ts in wl.targets.items():
            if c not in by_id or not by_id[c].has("client"):
                self.error(f"workload.targets.{c}", f"{c!r} is not a task source node")
                continue
            if by_id[c].has("worker") and ts != [c]:
                self.error(f"workload.targets.{c}", "a client on a worker node hands its tasks to that worker; "
                           f"expected [{c}]")
            for j, t in enumerate(ts):
                if t not in by_id or not by_id[t].has("worker") or (t != c and t not in nbrs[c]):
                    self.error(f"workload.targets.{c}[{j}]", f"{t!r} is not a worker neighbour of {c!r}")
        for n in nodes:
            if (n.has("client") and not n.has("worker") and n.id not in wl.targets
                    and not any(by_id[j].has("worker") for j in nbrs[n.id])):
                self.error(f"node {n.id!r}", "a task source without a worker needs a worker neighbour")
        self.check_arrivals(wl)
        self.check_deadlines(wl)
        trace = None
        if wl.trace is not None:
            trace = self.trace(self.file(wl.trace), by_id, wl)
        return Workload(
            task_types=tasks,
            arrival=wl.arrival,
            client_rates=tuple(sorted(wl.rates.items())),
            client_targets=tuple((c, tuple(ts)) for c, ts in sorted(wl.targets.items())),
            trace=trace,
            source=wl.source or "",
            jobs=self.jobs(wl),
        )

    def jobs(self, wl: WorkloadCfg) -> Jobs | None:
        """``workload.jobs``: the listed DAGs, those of an Alibaba trace, or the generator."""
        cfg = wl.jobs
        if cfg is None:
            return None
        if cfg.alibaba is not None:
            where = "workload.jobs.alibaba.file"
            try:
                dags = read_dags(self.file(cfg.alibaba.file), Conversion(**cfg.alibaba.model_dump(exclude={"file"})))
            except TraceError as exc:
                self.error(where, f"{exc} (expected a batch_task.csv of the Alibaba trace v2018)")
                return None
            jobs = Jobs(dags=tuple(dags))
        else:
            jobs = Jobs(dags=tuple(cfg.dags or ()), generator=cfg.generator)
        if why := self.too_long(jobs.longest_deadline):
            self.error("workload.jobs", why)
        self.check_job_types(wl, jobs)
        return jobs

    def type_index(self, wl: WorkloadCfg, name: str) -> int | str:
        """The index in ``workload.tasks`` of the task type ``name``, or why there is none."""
        named = [i for i, t in enumerate(wl.tasks) if t.name == name]
        if len(named) == 1:
            return named[0]
        if not named:
            return (f"expected the name of a task type of workload.tasks ({', '.join(repr(t.name) for t in wl.tasks)})"
                    f", got {name!r}")
        return f"{len(named)} task types of workload.tasks are named {name!r}; give each a name of its own"

    def check_job_types(self, wl: WorkloadCfg, jobs: Jobs) -> None:
        """A job's task names a task type of its own file, and a type with a payload is named by some task of
        a job: with jobs, a task runs a payload only when its type names one (an Alibaba job's tasks name none)."""
        named: set[str] = set()
        places = [("workload.jobs.generator.type", jobs.generator.type)] if jobs.generator is not None else []
        if wl.jobs is not None and wl.jobs.dags is not None:
            places += [(f"workload.jobs.dags[{j}].tasks[{k}].type", t.type) for j, job in enumerate(wl.jobs.dags)
                       for k, t in enumerate(job.tasks)]
        for where, name in places:
            if name is None:
                continue
            if isinstance(why := self.type_index(wl, name), str):
                self.error(where, why)
            named.add(name)
        for i, t in enumerate(wl.tasks):
            if t.payload is not None and t.name not in named:
                self.error(f"workload.tasks[{i}].payload", f"no task of workload.jobs is of type {t.name!r}; with jobs "
                           "a task runs a payload when it names its type (dags[].tasks[].type or generator.type; an "
                           "Alibaba job's tasks have none)")

    def check_arrivals(self, wl: WorkloadCfg) -> None:
        """Every rate a source may draw with, times dt, within MAX_TASKS_PER_TICK."""
        a, dt = wl.arrival, self.cfg.simulation.dt
        peaks = {f"workload.arrival.{key}": getattr(a, key) for key in a.peak_keys}
        peaks.update({f"workload.rates.{c}": rate for c, rate in wl.rates.items()})
        for where, rate in peaks.items():
            if rate * dt > MAX_TASKS_PER_TICK:
                self.error(where, f"{rate:g} tasks/s with dt = {dt:g} s is {rate * dt:g} tasks a tick per source; "
                                  f"expected at most {MAX_TASKS_PER_TICK:g}")

    def check_deadlines(self, wl: WorkloadCfg) -> None:
        """Every deadline within LONGEST_DEADLINE_TICKS ticks (a trace's rows are checked as they are read)."""
        for i, t in enumerate(wl.tasks):
            if why := self.too_long(t.longest_deadline):
                self.error(f"workload.tasks[{i}].deadline", why)

    def too_long(self, deadline: float) -> str | None:
        """Why ``deadline`` (seconds) is past LONGEST_DEADLINE_TICKS ticks, or None."""
        dt = self.cfg.simulation.dt
        if deadline / dt <= LONGEST_DEADLINE_TICKS:
            return None
        return (f"a deadline of {deadline:g} s is {deadline / dt:g} ticks of dt = {dt:g} s; expected at most "
                f"2^50 ({LONGEST_DEADLINE_TICKS:.2g}) ticks")

    def trace(self, path: Path, by_id: dict[str, NodeSpec], wl: WorkloadCfg) -> tuple[TraceRow, ...] | None:
        """The rows of a trace file: its columns, and optionally ``type`` (the name of a task type of
        ``workload.tasks``, whose payload the row's task runs; empty: none)."""
        columns = TraceRow.columns()
        sizes = columns[2:]
        where = "workload.trace"
        try:
            with path.open(newline="") as fh:
                reader = csv.DictReader(fh)
                header = [c.strip() for c in reader.fieldnames or ()]
                if header not in (columns, [*columns, "type"]):
                    self.error(where, f"{path}: expected the header {','.join(columns)} (and optionally type)")
                    return None
                rows, untyped = [], False  # untyped: a row whose type is no task type's
                for line, rec in enumerate(reader, start=2):
                    name = (rec.get(reader.fieldnames[-1]) or "").strip() if len(header) > len(columns) else ""
                    kind = self.type_index(wl, name) if name else None
                    if isinstance(kind, str):
                        self.error(where, f"{path}:{line}: type: {kind}")
                        untyped = True
                        continue
                    try:
                        row = TraceRow(float(rec["time"]), rec["client"].strip(),
                                       TaskSize(*(float(rec[c]) for c in sizes)), kind)
                    except (TypeError, ValueError, AttributeError):
                        self.error(where, f"{path}:{line}: expected numbers in every column but 'client' and 'type'")
                        continue
                    if not all(math.isfinite(x) for x in (row.time, *row.size)):
                        self.error(where, f"{path}:{line}: expected finite numbers in every column but 'client'")
                        continue
                    if row.client not in by_id or not by_id[row.client].has("client"):
                        self.error(where, f"{path}:{line}: {row.client!r} is not a task source node")
                    bad = [c for c, x in zip(sizes, row.size, strict=True) if x <= 0]
                    if bad:
                        self.error(where, f"{path}:{line}: expected positive {', '.join(bad)}")
                    if row.time < 0:
                        self.error(where, f"{path}:{line}: expected time >= 0")
                    if why := self.too_long(row.size.deadline):
                        self.error(where, f"{path}:{line}: {why}")
                    rows.append(row)
        except FileNotFoundError:
            self.error(where, f"file not found: {path}")
            return None
        except UnicodeDecodeError:
            self.error(where, f"{path}: not a text file (expected a CSV of tasks)")
            return None
        except csv.Error as exc:  # e.g. a NUL byte
            self.error(where, f"{path}: not a CSV file: {exc}")
            return None
        except OSError as exc:  # a directory, no permission
            self.error(where, f"{path}: cannot read it: {exc.strerror}")
            return None
        named = {r.type for r in rows}
        for i, t in enumerate(wl.tasks):
            if t.payload is not None and i not in named and not untyped:
                self.error(f"workload.tasks[{i}].payload", f"no row of {path.name} is of type {t.name!r}; a trace's "
                           "task runs a payload when its type column names it")
        return tuple(sorted(rows, key=lambda r: (r.time, r.client)))

