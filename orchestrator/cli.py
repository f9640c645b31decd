"""``orchestrator``: the command line of ZenohEdge.

    orchestrator launch topologies/aot2.yaml            # run a scenario over Zenoh processes
    orchestrator validate my_scenario.yaml              # check a scenario file
    orchestrator monitor                                # live dashboard of a running simulation
    orchestrator topology aot2                          # draw a scenario's network (runs/aot2-<time>/)
    orchestrator plot runs/aot2-20261123-101500         # time-series PNGs of a finished run
    orchestrator bench                                  # ticks/s against a bare Zenoh barrier

A bare ``orchestrator`` prints the help. Exit status: 0 success, 1 the run failed (a node died,
conservation broke, ...), 2 a bad scenario or bad arguments, 130 interrupted.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import json
import signal
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

from node_runtime.model.payload import PayloadError, run_log
from node_runtime.model.policies import POLICIES
from node_runtime.model.rng import MAX_SEED
from node_runtime.model.spec import Scenario, episode_too_long
from node_runtime.runtime import access, cli_options
from node_runtime.runtime.keys import new_sim_id
from node_runtime.runtime.layout import DEFAULT_LAYOUT_HELP, LAYOUT_HELP, Choice, ProcessLayout, layout_for
from node_runtime.runtime.security import SecurityError
from orchestrator import local_sims
from orchestrator.arguments import COUNT, NON_NEGATIVE, POLICY, POSITIVE, STEPS, integer, layout_name
from orchestrator.clock import ClockError, ProcessFailed
from orchestrator.metrics import SUMMARY, ConservationError, TickReport, unfinished, write_summary
from orchestrator.placement import load_placement
from orchestrator.scenario import ScenarioError, costs, load_scenario
from orchestrator.serve import is_loopback, reachable
from orchestrator.session import (
    RemoteHosts,
    RouterSettings,
    RouterUnavailable,
    SimIdInUse,
    Simulation,
    node_policies,
)
from orchestrator.version import version_line
from orchestrator.viewers import monitor
from orchestrator.viewers.progress import progress_steps
from orchestrator.viewers.summary import policy_text, rows
from topologies import bundled_scenarios

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130
LOCAL = "local"  # the node-side policy that keeps every task on its own node

TRACE_LINES = 12  # of a failed node's traceback, shown under the error



def fail(message: str) -> None:
    """One plain line on stderr: never wrapped or styled, so scripts and users can grep it."""
    print(message, file=sys.stderr, flush=True)


class UsageError(Exception):
    """A bad combination of arguments: one line on stderr, exit status 2."""


class Terminated(BaseException):
    """SIGTERM, turned into an exception so that cleanup runs exactly as for Ctrl-C."""


def _on_sigterm(signum: int, frame: Any) -> None:
    raise Terminated()


def run_dir(name: str) -> Path:
    """Where a command writes by default: runs/<name>-<time>, under the current directory, never in it."""
    return Path("runs") / f"{name}-{dt.datetime.now():%Y%m%d-%H%M%S}"


# ----- launch -----

def cmd_launch(args: argparse.Namespace) -> int:
    scenario = with_payload_log(load_scenario(args.scenario), args)
    if args.steps and (why := episode_too_long(args.steps, scenario.decision_interval)):
        raise UsageError(f"--steps {args.steps}: {why} (decision_interval {scenario.decision_interval})")
    ticks = (args.steps or scenario.steps) * scenario.decision_interval
    out = Path(args.out) if args.out else run_dir(scenario.name)
    if args.serve and args.transport != "zenoh":
        raise UsageError("--serve needs --transport zenoh: other processes reach the simulation over Zenoh")
    if args.episodes == 0 and not args.serve:
        raise UsageError("--episodes 0 runs no episode: it is for --serve, which then only serves")
    choice = Choice(args.layout) if args.layout else layout_for(scenario, args.transport, placed=bool(args.placement))
    layout = choice.layout
    host, port = parse_listen(args.listen) if args.listen else ("127.0.0.1", None)
    placement = None
    if args.placement:
        if args.transport != "zenoh":
            raise UsageError("--placement needs --transport zenoh")
        placement = load_placement(args.placement, ProcessLayout(scenario, layout))
    security, zenoh_settings = cli_options.security_options(args)
    if security is None and not is_loopback(host) and not args.insecure:
        raise UsageError(f"--listen {args.listen}: without --security anyone who reaches this host can drive the "
                         "simulation and pose as its processes; add --security DIR (deploy/README.md), or "
                         "--insecure on a network you trust")
    if security is not None and (clash := sorted(set(placement or {}) & set(access.IDENTITIES))):
        raise UsageError(f"--placement: group {clash[0]!r} is reserved with --security (identities "
                         f"{', '.join(access.IDENTITIES)} exist already); rename the group")
    sim_id = args.sim_id or new_sim_id()
    console = Console(stderr=True, highlight=False, quiet=args.quiet)
    seed = args.seed if args.seed is not None else scenario.seed
    console.print(f"[bold]{scenario.name}[/]: {len(scenario.nodes)} nodes, {len(scenario.controllers)} controllers, "
                  f"{len(scenario.clients)} task sources; {ticks} ticks of {scenario.dt:g} s; "
                  f"transport {args.transport} ({layout}); seed {seed}; "
                  f"{policy_text(node_policies(scenario, args.policy))}")
    if choice.note is not None:
        console.print(choice.note, markup=False, soft_wrap=True)

    def waiting(groups: dict[str, list[str]], endpoint: str) -> None:
        where = reachable(endpoint)[0]
        console.print(f"waiting for {sum(map(len, groups.values()))} processes on other hosts; run there:")
        for group in groups:
            login = f" --security <dir of {group}>" if security is not None else ""
            console.print(f"  zenohedge-node --connect {where} --sim {sim_id} --group {group}{login}", markup=False)

    router = RouterSettings(listen_host=host, port=port, join=tuple(args.connect or ()), security=security,
                            zenoh_settings=zenoh_settings)
    remote = None if placement is None else RemoteHosts(placement=placement, on_waiting=waiting)
    t0 = time.perf_counter()
    with output_dir(out if args.episodes == 1 else out / "episode-0", needed=args.episodes > 0,
                    scenario=scenario.name), \
            Simulation.open(scenario, args.transport, layout=layout, timeout=args.timeout, sim_id=sim_id,
                            router=router, remote=remote) as sim, \
            listed(sim, console):
        if args.transport == "zenoh":
            addresses = reachable(sim.endpoint)
            also = f" (reached at {', '.join(addresses)})" if addresses != [sim.endpoint] else ""
            console.print(f"router {sim.endpoint}{also}, simulation id [bold]{sim.keys.sim_id}[/], "
                          f"{len(sim.plan.procs)} processes ready in {sim.startup_s:.2f} s")
            if security is None and not is_loopback(host):  # said even with --quiet
                fail(f"warning: --insecure: plain TCP on {host}, no TLS, no login: whoever reaches this host can "
                     "drive the simulation")
        if args.serve:
            at = reachable(sim.endpoint)[0]
            console.print(f"serving: watch it with `orchestrator monitor` (from another host: `orchestrator monitor "
                          f"--connect {at} --sim {sim.keys.sim_id}`); attach an environment with "
                          f"ZenohEdgeEnv(connect=\"{at}\", sim_id=\"{sim.keys.sim_id}\")", markup=False)
        for episode in range(args.episodes):
            where = out if args.episodes == 1 else out / f"episode-{episode}"
            sim.metrics.stream(where)  # ticks.csv and nodes.csv grow as the episode runs
            try:
                summary = run_episode(sim, ticks, None if seed is None else seed + episode, args, console)
                summary["run"]["total_wall_s"] = round(time.perf_counter() - t0, 3)
                sim.metrics.write(where, summary)
            except (KeyboardInterrupt, Terminated, ClockError, ConservationError) as exc:
                keep_partial(sim, where, exc, t0, console)
                raise
            if args.json:
                print(json.dumps(summary, indent=2))
            else:
                screen = Console(highlight=False)
                screen.print(summary_table(summary))
                if (note := local_note(summary["policy"])) is not None:
                    screen.print(note, soft_wrap=True)
            console.print(f"results: {where}/summary.json, ticks.csv, nodes.csv")
        if args.serve:
            try:
                sim.server.wait(ready=lambda: console.print("serving until Ctrl-C"))
            finally:
                if args.episodes:
                    record_serving(sim, where / "summary.json")
    return EXIT_OK


def with_payload_log(scenario: Scenario, args: argparse.Namespace) -> Scenario:
    """The scenario with the run's ``--payload-record`` or ``--payload-replay`` file (docs/model.md, "Payloads")."""
    if not (args.payload_record or args.payload_replay):
        return scenario
    option = "--payload-record" if args.payload_record else "--payload-replay"
    if not any(t.payload is not None for t in scenario.workload.task_types):
        raise UsageError(f"{option}: {scenario.name} has no task type with a payload")
    try:
        return scenario.replace(payload_log=run_log(args.payload_record, args.payload_replay))
    except (PayloadError, OSError) as exc:
        raise UsageError(f"{option}: {exc}") from None


def record_serving(sim: Simulation, path: Path) -> None:
    """Bring the last episode's summary.json up to date once serving ends: what drivers did to the clock, and
    what the orchestrator refused, while it served (docs/bus.md, "Rejected messages")."""
    summary = json.loads(path.read_text())
    summary["run"]["control"] = dict(sim.server.counts)
    summary["run"]["rejected_messages"]["orchestrator"] = dict(sorted(sim.transport.rejections.counts.items()))
    path.write_text(json.dumps(summary, indent=2) + "\n")


@contextlib.contextmanager
def output_dir(first: Path, needed: bool, scenario: str) -> Iterator[None]:
    """Make the first episode's directory and write its incomplete summary.json there before any process
    starts, so that a path that cannot be one, or cannot be written, is a line, not a traceback after the
    start; and remove them again if the run fails before an episode starts."""
    if not needed:
        yield
        return
    made = [p for p in (first, *first.parents) if not p.exists()]
    placeholder = unfinished(scenario)
    try:
        first.mkdir(parents=True, exist_ok=True)
        write_summary(first, placeholder)
    except OSError as exc:
        _remove_empty(made)
        where = exc.filename2 or exc.filename or first  # a rename names the file it replaces second
        raise UsageError(f"--out {where}: cannot write the results there: {exc.strerror}") from None
    try:
        yield
    except BaseException:
        with contextlib.suppress(OSError, ValueError):
            if made and json.loads((first / SUMMARY).read_text()) == placeholder:  # no episode started
                (first / SUMMARY).unlink()
        _remove_empty(made)
        raise


def _remove_empty(made: list[Path]) -> None:
    """The directories made for a run, deepest first, those that are empty: partial results stay."""
    for path in made:
        with contextlib.suppress(OSError):
            path.rmdir()


INTERRUPTIONS = {KeyboardInterrupt: "interrupted (Ctrl-C)", Terminated: "terminated (SIGTERM)"}


def keep_partial(sim: Simulation, where: Path, exc: BaseException, t0: float, console: Console) -> None:
    """Write what an episode that did not finish measured: summary.json marked ``incomplete`` (why, and
    the last tick recorded) and the CSV rows so far. With no tick recorded, summary.json alone says why."""
    reason = INTERRUPTIONS.get(type(exc)) or f"{type(exc).__name__}: {exc}"
    sim.metrics.settle()
    if not sim.metrics.n_ticks:
        sim.metrics.close_stream()
        where.mkdir(parents=True, exist_ok=True)
        write_summary(where, {"scenario": sim.scenario.name, "ticks": 0,
                              "incomplete": {"reason": reason, "last_tick": None}})
        console.print(f"no tick was recorded: {where}/summary.json says why", markup=False)
        return
    summary = sim.summary()
    summary["incomplete"] = {"reason": reason, "last_tick": sim.metrics.last_tick}
    summary["run"]["total_wall_s"] = round(time.perf_counter() - t0, 3)
    sim.metrics.write(where, summary)
    console.print(f"partial results ({sim.metrics.n_ticks} ticks): {where}/summary.json, ticks.csv, nodes.csv",
                  markup=False)


@contextlib.contextmanager
def listed(sim: Simulation, console: Console) -> Iterator[None]:
    """A Zenoh simulation is listed on this host (orchestrator.local_sims) while it runs, for a bare
    `orchestrator monitor`."""
    with contextlib.ExitStack() as stack:
        if sim.endpoint is not None:
            try:
                stack.enter_context(local_sims.registered(sim.keys.sim_id, sim.endpoint, sim.scenario.name))
            except local_sims.LocalSimsError as exc:
                console.print(f"not listed for `orchestrator monitor` on this host ({exc}): monitors need --connect",
                              markup=False)
        yield


def run_episode(sim: Simulation, ticks: int, seed: int, args: argparse.Namespace, console: Console) -> dict[str, Any]:
    """One episode with node-side policies, a progress bar, and optional pacing for live viewing."""
    progress = Progress(TextColumn("[progress.description]{task.description}"), BarColumn(),
                        MofNCompleteColumn(), TextColumn("{task.fields[stats]}"), TimeRemainingColumn(),
                        console=console, transient=True, disable=args.quiet)
    period = 1.0 / args.tick_rate if args.tick_rate else 0.0
    next_at = [time.perf_counter()]
    with progress:
        task = progress.add_task("ticks", total=ticks, stats="")
        every = max(1, ticks // 200)

        def on_tick(r: TickReport) -> None:
            if r.tick % every == 0 or r.tick == ticks - 1:
                progress.update(task, completed=r.tick + 1, stats=(
                    f"gen {r['generated']}  done {r['completed']}  drop {r['dropped']}  in-system {r['in_system']}"))
            if period:  # pace the run for people watching a monitor
                next_at[0] += period
                time.sleep(max(0.0, next_at[0] - time.perf_counter()))

        return sim.run(ticks, seed=seed, policy=args.policy, on_tick=on_tick)


def parse_listen(text: str) -> tuple[str, int | None]:
    """HOST:PORT (or tcp/HOST:PORT) -> (host, port)."""
    text = text.removeprefix("tcp/").removeprefix("tls/")
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit():
        raise UsageError(f"--listen: expected HOST:PORT such as 0.0.0.0:7447, not {text!r}")
    return host, int(port)


def summary_table(s: dict[str, Any]) -> Table:
    """The episode's numbers (the catalogue's TABLE metrics), the policy in the title, the speed last."""
    run = s["run"]
    table = Table(title=f"{s['scenario']} — {s['ticks']} ticks, seed {s['seed']}, {policy_text(s['policy'])}",
                  show_header=False, title_justify="left")
    table.add_column(style="bold")
    table.add_column(justify="right")
    for k, v in rows(s):
        table.add_row(k, v)
    table.add_row("speed", f"{run['ticks_per_s']} ticks/s  ({run['transport']}, {run['layout']}, "
                           f"{run['processes']} process{'es' if run['processes'] != 1 else ''})")
    return table


def local_note(policy: str | list[str]) -> str | None:
    """Why nothing was offloaded, when every controller kept its tasks."""
    if policy in (LOCAL, [LOCAL]):
        return f"policy {LOCAL} keeps every task on its own node: pass --policy least_queue to offload"
    return None


# ----- bench -----

def cmd_bench(args: argparse.Namespace) -> int:
    from orchestrator.viewers import bench

    console = Console(stderr=True, highlight=False)
    configs = [c for c in bench.CONFIGS if c[0] in args.transports]
    with progress_steps(len(args.scenarios) * len(configs), "bench", console=console) as step:
        rows = bench.run(args.scenarios, args.ticks, configs, args.rounds, progress=step)
    table = Table(title=f"ticks/s, medians of {args.rounds} alternating chunks of {args.ticks // args.rounds} ticks "
                        "(random policy); barrier = bare Zenoh barrier, same process count", title_justify="left",
                  caption=f"measured with {version_line()}", caption_justify="left")
    for col in ("scenario", "transport", "layout", "processes", "ticks/s", "barrier ticks/s", "ratio"):
        table.add_column(col, justify="left" if col in ("scenario", "transport", "layout") else "right")
    for r in rows:
        table.add_row(r.scenario, r.transport, r.layout, str(r.processes), f"{r.ticks_per_s:,.0f}",
                      "-" if r.barrier_ticks_per_s is None else f"{r.barrier_ticks_per_s:,.0f}",
                      "-" if r.ratio is None else f"{r.ratio:.2f}")
    Console(highlight=False).print(table)
    if args.out:
        bench.save(rows, Path(args.out))
        console.print(f"saved {args.out}")
    return EXIT_OK


# ----- topology, plot (matplotlib is imported only when they run) -----

def cmd_topology(args: argparse.Namespace) -> int:
    from orchestrator.viewers import draw

    return draw.cmd_topology(args, run_dir)


def cmd_plot(args: argparse.Namespace) -> int:
    from orchestrator.viewers import plots

    return plots.cmd_plot(args)


# ----- trace -----

def cmd_trace(args: argparse.Namespace) -> int:
    from topologies.alibaba import Conversion, TraceError, convert, write

    scenario = load_scenario(args.scenario)
    conversion = Conversion(frequency=args.frequency, memory_bytes=args.memory, output_ratio=args.output_ratio,
                            deadline_factor=args.deadline_factor, time_scale=args.time_scale, limit=args.limit)
    try:
        rows = convert(Path(args.input), list(scenario.clients), conversion)
    except TraceError as exc:
        fail(f"orchestrator trace: {exc}")
        return EXIT_USAGE
    out = Path(args.out) if args.out else run_dir(f"{scenario.name}-{args.format}") / "trace.csv"
    try:
        if not args.out:
            out.parent.mkdir(parents=True, exist_ok=True)
        write(rows, out)
    except OSError as exc:
        fail(f"orchestrator trace: cannot write {out}: {exc.strerror}")
        return EXIT_USAGE
    span = rows[-1]["time"] if rows else 0
    print(f"{len(rows)} tasks over {span:g} s for {len(scenario.clients)} task sources -> {out} "
          f"(use it with `workload: {{trace: {out.name}}}`, the path relative to the scenario file)")
    return EXIT_OK


# ----- validate -----

def cmd_validate(args: argparse.Namespace) -> int:
    sc = load_scenario(args.scenario)
    print(f"{len(sc.nodes)} nodes, {sc.undirected_links} links, {len(sc.controllers)} controllers, "
          f"{len(sc.clients)} task sources")
    for line in costs.report(sc):
        print(line)
    return EXIT_OK


# ----- parser -----

def scenarios_help() -> str:
    """The bundled scenarios, as every command that takes a scenario accepts them by name."""
    return (f"Bundled scenarios, by name in place of a file: {', '.join(bundled_scenarios())}. "
            "The format of a scenario file: docs/scenario.md.")


def build_parser() -> argparse.ArgumentParser:
    scenarios = scenarios_help()
    parser = argparse.ArgumentParser(
        prog="orchestrator",
        description="ZenohEdge: a distributed task-offloading emulator. Every worker, client and controller "
                    "runs as its own process and talks over Eclipse Zenoh under a simulated clock.",
        epilog=scenarios)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("launch", help="run a scenario and save its metrics", epilog=scenarios,
                       description="Run one episode of a scenario with node-side policies, show progress, print a "
                                   "summary and write summary.json, ticks.csv and nodes.csv.")
    p.add_argument("scenario", help="scenario YAML file, or a bundled name such as aot2")
    p.add_argument("--steps", type=STEPS, help="decision steps to run, at most 2^31 ticks in all (default: the "
                                              "scenario's simulation.steps)")
    p.add_argument("--seed", type=integer(0, MAX_SEED),
                   help="random seed, from 0 to 2^62 - 1 (default: the scenario's simulation.seed)")
    p.add_argument("--transport", choices=("zenoh", "inproc"), default="zenoh",
                   help="zenoh: node processes (see --layout) around a Zenoh router (default); inproc: all roles in "
                        "this process over an in-memory bus (fast, same results)")
    p.add_argument("--layout", type=layout_name, metavar="LAYOUT",
                   help=f"process layout: {LAYOUT_HELP}. Default: single inproc; over zenoh {DEFAULT_LAYOUT_HELP}")
    p.add_argument("--policy", type=POLICY, metavar="POLICY",
                   help=f"node-side decision policy for every controller: {', '.join(sorted(POLICIES))}, or a "
                        "Policy subclass of your own as module:Class (docs/extending.md; default: the scenario's)")
    p.add_argument("--out", metavar="DIR", help="output directory (default: runs/<scenario>-<time>)")
    p.add_argument("--timeout", type=cli_options.TIMEOUT, default=30.0, metavar="S",
                   help="seconds to wait for a tick before declaring a process hung (default 30, at most 1e6)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON instead of a table")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar or status lines")
    p.add_argument("--episodes", type=integer(0), default=1, metavar="N",
                   help="episodes to run (default 1; with --serve, 0 runs none and only serves)")
    p.add_argument("--serve", action="store_true",
                   help="keep the simulation up after the episodes: monitors and ZenohEdgeEnv(connect=...) can "
                        "attach from other processes or hosts until Ctrl-C")
    p.add_argument("--listen", metavar="HOST:PORT",
                   help="where the router listens (default 127.0.0.1 on a free port); e.g. 0.0.0.0:7447 to serve "
                        "other hosts, which needs --security or --insecure")
    p.add_argument("--insecure", action="store_true",
                   help="let --listen on an address other hosts reach go without --security: plain TCP, no TLS, no "
                        "login, so that anyone who reaches the port can drive the simulation (a trusted network only)")
    p.add_argument("--placement", metavar="FILE",
                   help="run the nodes listed in FILE's groups on other hosts with zenohedge-node (see deploy/); "
                        "use with --listen")
    p.add_argument("--sim-id", metavar="ID", type=cli_options.sim_id,
                   help="simulation id (default: random); fix it to script remote hosts")
    p.add_argument("--connect", action="append", metavar="ENDPOINT", type=cli_options.endpoint,
                   help="join the router to another Zenoh router (e.g. another simulation's), so that several "
                        "simulations share one network; repeatable")
    p.add_argument("--tick-rate", type=POSITIVE, metavar="HZ",
                   help="run at most HZ ticks per second, to watch a run live with `orchestrator monitor`")
    payload = p.add_mutually_exclusive_group()
    payload.add_argument("--payload-record", metavar="FILE",
                         help="run the task types' payloads and write each measured CPU time to FILE (JSON lines), "
                              "from which --payload-replay repeats the run exactly (docs/model.md, \"Payloads\")")
    payload.add_argument("--payload-replay", metavar="FILE",
                         help="serve the payloads' tasks for the times recorded in FILE instead of running them")
    cli_options.add_security_options(
        p, identity="orchestrator",
        config_help="a Zenoh JSON5 configuration file merged last into the router's configuration, for what the "
                    "options above do not set (its settings win)")
    p.set_defaults(func=cmd_launch)

    p = sub.add_parser("bench", help="measure ticks/s against a bare Zenoh barrier",
                       description="Measure emulator ticks/s for each scenario, transport and layout, next to a bare "
                                   "Zenoh barrier (one publication to N processes, N replies, no work) with the same "
                                   "process count, all in one run. Ratio = emulator / barrier.")
    p.add_argument("scenarios", nargs="*", default=["aot1", "aot2", "aot3", "aot4"],
                   help="scenario files or bundled names (default: aot1 aot2 aot3 aot4)")
    p.add_argument("--ticks", type=COUNT, default=500, help="ticks measured per configuration (default 500)")
    p.add_argument("--rounds", type=COUNT, default=5,
                   help="alternating chunks of emulator and barrier ticks; medians are reported (default 5)")
    p.add_argument("--transports", nargs="+", choices=("inproc", "zenoh"), default=["inproc", "zenoh"])
    p.add_argument("--out", metavar="FILE", help="also write the rows as JSON")
    p.set_defaults(func=cmd_bench)

    p = sub.add_parser(
        "topology", help="draw a scenario's network to a PNG", epilog=scenarios,
        description="Draw the network of a scenario without running it: nodes at their positions (metres), "
                    "coloured by tier, circles for controllers (agents), squares for worker-only nodes, a dark "
                    "outline on task sources, size by capacity and link width by rate (both log scale).")
    p.add_argument("scenario", metavar="SCENARIO", help="scenario YAML file, or a bundled name such as aot2")
    p.add_argument("--png", metavar="FILE",
                   help="PNG file to write (folders are created; default: runs/<scenario>-<time>/topology.png)")
    p.add_argument("--title", metavar="T", help="heading instead of the scenario name (counts are always shown)")
    p.add_argument("--frames", type=COUNT, metavar="N",
                   help="moving nodes: a strip of N frames of the positions over time instead of one picture")
    p.add_argument("--every", type=COUNT, metavar="K",
                   help="with --frames: ticks between frames (default: the frames spread over the episode)")
    p.add_argument("--seed", type=integer(0, MAX_SEED),
                   help="with --frames: the seed of the walks (default: the scenario's simulation.seed)")
    p.set_defaults(func=cmd_topology)

    p = sub.add_parser(
        "plot", help="draw PNG time series of a finished run",
        description="Read summary.json, ticks.csv and nodes.csv from a directory written by `orchestrator "
                    "launch` and write overview.png, queues.png, drops.png, response_time.png and energy.png.")
    p.add_argument("run_dir", metavar="RUN_DIR", help="a run directory, e.g. runs/aot2-20250101-120000")
    p.add_argument("--out", metavar="DIR", help="where to write the PNGs (default: RUN_DIR/plots)")
    p.set_defaults(func=cmd_plot)

    p = sub.add_parser(
        "trace", help="turn an Alibaba cluster trace into a trace workload",
        description="Convert Alibaba cluster-trace v2018 batch_task.csv into the emulator's trace CSV, the way the "
                    "PeersimGym paper reads it: each job becomes one task arriving at its start, with its peak CPU "
                    "x duration x --frequency instructions and its peak memory as data size; tasks go to the "
                    "scenario's task sources in turn.")
    p.add_argument("format", choices=("alibaba",), help="the input's format")
    p.add_argument("input", help="batch_task.csv (no header)")
    p.add_argument("--scenario", required=True, help="scenario whose task sources receive the tasks")
    p.add_argument("--out", metavar="FILE",
                   help="trace CSV to write (default: runs/<scenario>-alibaba-<time>/trace.csv)")
    p.add_argument("--frequency", type=POSITIVE, default=4.0e6, help="instructions/s of one core (default 4e6)")
    p.add_argument("--memory", type=POSITIVE, default=1.0e9, help="bytes that plan_mem = 100 stands for (default 1e9)")
    p.add_argument("--output-ratio", type=NON_NEGATIVE, default=1.0, help="output bytes / input bytes (default 1)")
    p.add_argument("--deadline-factor", type=POSITIVE, default=3.0, help="deadline = factor x job duration (default 3)")
    p.add_argument("--time-scale", type=POSITIVE, default=1.0, help="emulated seconds per trace second (default 1)")
    p.add_argument("--limit", type=COUNT, help="keep the earliest N jobs")
    p.set_defaults(func=cmd_trace)

    monitor.add_parser(sub)

    p = sub.add_parser("validate", help="check a scenario file", epilog=scenarios,
                       description="Load and validate a scenario. Prints 'N nodes, E links, C controllers, S task "
                                   "sources', then what one task of each type costs alone on each device against its "
                                   "deadline (with a 'warning:' line where it cannot meet it), and exits 0; or one "
                                   "line per problem and exits 2.")
    p.add_argument("scenario")
    p.set_defaults(func=cmd_validate)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    argv = sys.argv[1:] if argv is None else argv
    if not argv:  # a bare `orchestrator`: the help, as pip gives it
        parser.print_help()
        return EXIT_OK
    args = parser.parse_args(argv)
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        return args.func(args)
    except ScenarioError as exc:
        for line in exc.errors:
            fail(line)
        return EXIT_USAGE
    except (UsageError, SimIdInUse, RouterUnavailable, SecurityError) as exc:
        fail(f"orchestrator: {exc}")
        return EXIT_USAGE
    except (ClockError, ConservationError) as exc:
        fail(f"error: {exc}")
        if isinstance(exc, ProcessFailed) and exc.trace:  # the node's own traceback, its end
            for line in exc.trace.strip().splitlines()[1:][-TRACE_LINES:]:
                fail(f"  {line}")
        return EXIT_FAILED
    except (KeyboardInterrupt, Terminated):
        fail("interrupted: every node process has been stopped")
        return EXIT_INTERRUPTED
    finally:
        signal.signal(signal.SIGTERM, previous)


if __name__ == "__main__":
    sys.exit(main())
