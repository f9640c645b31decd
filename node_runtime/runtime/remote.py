"""``zenohedge-node``: run a group of node processes of a simulation served from another host.

    zenohedge-node --connect tcp/10.0.0.1:7447 --sim lab1 --group edge-a

The orchestrator (``orchestrator launch … --placement FILE``) owns the clock and the router; this
command asks it (query ``…/session``) for the scenario, the layout and the processes placed in
``--group``, starts them here through the same fork server as a local run, and stays until they
end. They end when the orchestrator stops the run or vanishes; Ctrl-C here stops them too.

This command's session is a Zenoh router joined to the orchestrator's: the processes started here
connect to it over a unix socket in a private directory, so that mail between them stays on this host
and the orchestrator's router holds one session per host, not one per process. The processes report
the end of each tick to this command, which forwards a tick's reports as one message
(``aggregator.py``): the orchestrator hears one report per host and tick, not one per process. Before
anything starts, this command registers the group (``…/register/<group>``) and gets the keys its processes
and its aggregator prove their reports with (``origin.py``); a group registers once.
``--direct`` connects every process straight to the orchestrator's router instead, each reporting on
its own; ``--no-aggregate`` keeps the router but lets each process report on its own.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import os
import signal
import sys
import tempfile
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from node_runtime.model.spec import Scenario
from node_runtime.runtime import process as node_process
from node_runtime.runtime.access import LOCAL_LINK, access_control
from node_runtime.runtime.aggregator import DoneAggregator
from node_runtime.runtime.answers import session_answer
from node_runtime.runtime.cli_options import TIMEOUT, add_security_options, add_sim_options, security_options
from node_runtime.runtime.forkserver import ForkServer
from node_runtime.runtime.keys import Keys
from node_runtime.runtime.layout import Layout, ProcessLayout
from node_runtime.runtime.origin import KEY_BYTES, Keyring
from node_runtime.runtime.process import ORCHESTRATOR, ProcSpec
from node_runtime.runtime.security import Security, SecurityError
from node_runtime.runtime.zenoh_bus import ZenohTransport

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2


# The host's router gives up at once when the orchestrator's router does not answer, as a client does
FAIL_FAST = {"connect/timeout_ms": 0, "connect/exit_on_failure": True}


class GroupError(Exception):
    """This host cannot take part: the message, one line, says why."""


@dataclass(frozen=True)
class GroupInfo:
    """What the orchestrator's ``…/session`` answer tells this host."""

    scenario: Scenario
    layout: Layout
    placement: dict[str, list[str]]  # every group -> its processes
    group: str  # this host's
    ready_timeout: float  # seconds a process waits for its peers' subscriptions (hosts may join late)
    lease_s: float  # how long a router keeps a silent process's session: beyond the clock's --timeout

    @property
    def procs(self) -> list[str]:
        return self.placement[self.group]


def run_group(endpoint: str, keys: Keys, group: str, timeout: float = 30.0, security: Security | None = None,
              settings: dict[str, Any] | None = None, direct: bool = False, aggregate: bool = True) -> int:
    """``security`` and ``settings`` (a Zenoh configuration): for this command's sessions and every process
    started. ``direct``: every process opens its own session to ``endpoint``, with no router on this host.
    ``aggregate``: behind this host's router, forward the processes' reports of a tick as one message."""
    try:
        transport = connect(lambda: ZenohTransport.client(endpoint, security, settings), endpoint)
        try:
            info = group_info(transport, endpoint, keys, group, timeout)
            keyring = register(transport, endpoint, keys, group, info.procs, timeout)
        except GroupError:
            transport.close()
            raise
        transport.close()  # what follows announces the simulation's lease (as the orchestrator said it)
        lease = {"transport/link/tx/lease": round(info.lease_s * 1000)}
        if direct:
            transport = connect(lambda: ZenohTransport.client(endpoint, security, {**lease, **(settings or {})}),
                                endpoint)
            return run_processes(transport, info, keyring, endpoint, keys, security, settings)
        with tempfile.TemporaryDirectory(prefix="zenohedge-node-") as folder:  # mode 0700: this user's only
            local = f"{LOCAL_LINK}/{folder}/router.sock"
            rules = {}
            if security is not None:  # the orchestrator's rules, for what this host's processes send each other
                plan = ProcessLayout(info.scenario, info.layout)
                rules = {"access_control": access_control(keys, plan, info.placement, on_host=True)}
            router = connect(lambda: ZenohTransport.router(local, [endpoint], host_login(security, Path(folder)),
                                                           {**FAIL_FAST, **lease, **rules, **(settings or {})}),
                             endpoint)
            return run_processes(router, info, keyring, local, keys, security, settings, aggregate)
    except GroupError as exc:
        print(f"zenohedge-node: {exc}", file=sys.stderr)
        return EXIT_USAGE


def connect(open_session: Callable[[], ZenohTransport], endpoint: str) -> ZenohTransport:
    try:
        return open_session()
    except Exception:  # zenoh.ZError: nothing answers, or the router refused our certificate or login
        raise GroupError(f"cannot connect to {endpoint}: no router answers there, or it refused this host's "
                         "certificate or login") from None


def group_info(transport: ZenohTransport, endpoint: str, keys: Keys, group: str, timeout: float) -> GroupInfo:
    """Ask the orchestrator for the simulation; raises GroupError when it has no group ``group``."""
    try:  # no answer; a refusal, e.g. from another ZenohEdge version; answers from two sessions; a wrong shape
        info = session_answer(transport.request(keys.session(), {"type": "session?"}, timeout=timeout), keys.session())
    except Exception as exc:
        raise GroupError(f"simulation {keys.sim_id!r} at {endpoint}: {exc}") from None
    placement = info.get("placement") or {}
    if group not in placement:
        raise GroupError(f"simulation {keys.sim_id} has no group {group!r}; groups: "
                         f"{', '.join(sorted(placement)) or '(none: launch it with --placement)'}")
    timing = [info.get(key) for key in ("ready_timeout", "lease_s")]
    if not all(isinstance(x, int | float) and not isinstance(x, bool) and x > 0 for x in timing):
        raise GroupError(f"simulation {keys.sim_id} at {endpoint} did not say how long its processes wait "
                         "(ready_timeout, lease_s): is it another ZenohEdge version?")
    return GroupInfo(Scenario.from_dict(info["scenario"]), info["layout"], placement, group, *map(float, timing))


def register(transport: ZenohTransport, endpoint: str, keys: Keys, group: str, procs: list[str],
             timeout: float) -> Keyring:
    """The keys of this group's processes, its host's and the clock's, from the orchestrator (once per group)."""
    try:
        answer = transport.request(keys.register(group), {"type": "register"}, timeout=timeout)
        keyring = Keyring.from_wire(answer)
    except Exception as exc:  # refused (registered already), no answer (another version), or not a registration
        raise GroupError(f"simulation {keys.sim_id} at {endpoint}: group {group} cannot register: {exc}") from None
    if not (set(procs) <= keyring.procs.keys() and group in keyring.hosts and all(
            type(k) is bytes and len(k) == KEY_BYTES for k in (keyring.clock, *keyring.procs.values(),
                                                              *keyring.hosts.values()))):
        raise GroupError(f"simulation {keys.sim_id} at {endpoint}: the registration of group {group} did not give "
                         "its keys: is it another ZenohEdge version?")
    return keyring


def host_login(security: Security | None, folder: Path) -> Security | None:
    """The host router's identity: the group's, accepting one login, the group's own, from local processes
    (a Zenoh router that logs in with a password refuses every session unless it has a list of logins)."""
    if security is None:
        return None
    users = folder / "users"
    users.write_text(f"{security.user}:{security.password}\n")
    return dataclasses.replace(security, users=str(users))


def run_processes(transport: ZenohTransport, info: GroupInfo, keyring: Keyring, endpoint: str, keys: Keys,
                  security: Security | None, settings: dict[str, Any] | None, aggregate: bool = False) -> int:
    """Start the group's processes, connected to ``endpoint``, and stay until they end; closes ``transport``.
    ``keyring``: the group's (``register``); ``aggregate``: their reports come here, and go on to the
    orchestrator one message a tick."""
    forks: ForkServer | None = None
    pids: list[int] = []
    procs = info.procs
    transport.rejections.who = f"zenohedge-node {info.group}"
    aggregator: DoneAggregator | None = None
    try:
        if aggregate and len(procs) > 1:
            aggregator = DoneAggregator(transport, keys, info.group, procs, keyring)
            transport.wait_matching([aggregator.out_key], info.ready_timeout)  # reports can go on: processes may start
        forks = ForkServer.shared()
        for proc in procs:
            spec = ProcSpec(proc, info.scenario, info.layout, endpoint, keys, keyring.of([proc]), security=security,
                            settings=settings, lease_s=info.lease_s, ready_timeout=info.ready_timeout,
                            done_key=keys.host_done(info.group, proc) if aggregator else None)
            pids.append(forks.start(proc, node_process.main, spec))
        print(f"zenohedge-node: group {info.group}: started {len(procs)} processes of simulation {keys.sim_id} "
              f"({', '.join(procs[:6])}{' ...' if len(procs) > 6 else ''}), connected to {endpoint}",
              file=sys.stderr, flush=True)

        gone, ended = threading.Event(), threading.Event()
        transport.watch_tokens(keys.alive(ORCHESTRATOR), lambda key, alive: alive or gone.set())
        threading.Thread(target=lambda: (forks.wait(pids, None), ended.set()), daemon=True).start()
        transport.dispatch(until=lambda: gone.is_set() or ended.is_set(),
                           idle=aggregator.flush if aggregator else None)
        left = forks.wait(pids, 10.0)
        failed = [(proc, pid) for proc, pid in zip(procs, pids, strict=True)
                  if (forks.exit_status(pid) or 0) not in (0, node_process.EXIT_ORPHANED)]
        for proc, pid in failed:
            why = forks.account(pid).strip()
            print(f"zenohedge-node: process {proc} exited with status {forks.exit_status(pid)}"
                  f"{': ' + why.splitlines()[0] if why else ''}", file=sys.stderr)
        return EXIT_FAILED if left or failed else EXIT_OK
    except KeyboardInterrupt:
        return EXIT_OK
    finally:
        transport.rejections.log_total()  # what the aggregator refused, as a node process says it at exit
        if forks is not None:
            for pid in forks.wait(pids, 0.0):
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGTERM)
            forks.wait(pids, 5.0)
        transport.close()


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="zenohedge-node",
        description="Run, on this host, the node processes placed in one group of a ZenohEdge simulation launched "
                    "elsewhere with `orchestrator launch SCENARIO --listen 0.0.0.0:PORT --placement FILE` (and "
                    "--security DIR, or --insecure).",
        epilog="See deploy/README.md.")
    add_sim_options(parser, required=True, connect_help="the orchestrator's router, e.g. tcp/10.0.0.1:7447",
                    sim_help="the simulation id (launch --sim-id fixes it)")
    parser.add_argument("--group", required=True, help="the group of the placement file this host runs")
    parser.add_argument("--timeout", type=TIMEOUT, default=30.0, help="seconds to wait for the orchestrator")
    parser.add_argument("--direct", action="store_true",
                        help="connect every process to the orchestrator's router (one session per process across "
                             "the network) instead of through a router this command runs on this host")
    parser.add_argument("--no-aggregate", dest="aggregate", action="store_false",
                        help="behind this host's router, let each process report the end of a tick to the "
                             "orchestrator itself, instead of this command forwarding the host's reports of a tick "
                             "as one message (the default)")
    add_security_options(parser, identity="group's",
                         config_help="a Zenoh JSON5 configuration file merged last into the configuration of this "
                                     "command's sessions and of the processes it starts (its settings win)")
    args = parser.parse_args(argv)
    try:
        security, settings = security_options(args)
    except SecurityError as exc:
        print(f"zenohedge-node: {exc}", file=sys.stderr)
        sys.exit(EXIT_USAGE)
    sys.exit(run_group(args.connect, Keys(args.sim, args.prefix), args.group, args.timeout, security, settings,
                       args.direct, args.aggregate))


if __name__ == "__main__":
    main()
