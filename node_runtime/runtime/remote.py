"""``zenohedge-node``: run a group of node processes of a simulation served from another host.

    zenohedge-node --connect tcp/10.0.0.1:7447 --sim lab1 --group edge-a

The orchestrator (``orchestrator launch … --placement FILE``) owns the clock and the router; this
command asks it (query ``…/session``) for the scenario, the layout and the processes placed in
``--group``, starts them here through the same fork server as a local run, and stays until they
end. They end when the orchestrator stops the run or vanishes; Ctrl-C here stops them too.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import threading
from typing import Any

from node_runtime.model.spec import Scenario
from node_runtime.runtime import process as node_process
from node_runtime.runtime.cli_options import add_security_options, add_sim_options, security_options
from node_runtime.runtime.forkserver import ForkServer
from node_runtime.runtime.keys import Keys
from node_runtime.runtime.process import ORCHESTRATOR, ProcSpec
from node_runtime.runtime.security import Security, SecurityError
from node_runtime.runtime.zenoh_bus import ZenohTransport

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2


def run_group(endpoint: str, keys: Keys, group: str, timeout: float = 30.0, security: Security | None = None,
              settings: dict[str, Any] | None = None) -> int:
    """``security`` and ``settings`` (a Zenoh configuration): for this session and every process started."""
    try:
        transport = ZenohTransport.client(endpoint, security, settings)
    except Exception:  # zenoh.ZError: nothing answers, or the router refused our certificate or login
        print(f"zenohedge-node: cannot connect to {endpoint}: no router answers there, or it refused this host's "
              "certificate or login", file=sys.stderr)
        return EXIT_USAGE
    forks: ForkServer | None = None
    pids: list[int] = []
    try:
        try:
            info = transport.request(keys.session(), {"type": "session?"}, timeout=timeout)
        except Exception as exc:  # no answer; or a refusal, e.g. from another ZenohEdge version
            print(f"zenohedge-node: simulation {keys.sim_id!r} at {endpoint}: {exc}", file=sys.stderr)
            return EXIT_USAGE
        placement = info.get("placement") or {}
        if group not in placement:
            print(f"zenohedge-node: simulation {keys.sim_id} has no group {group!r}; groups: "
                  f"{', '.join(sorted(placement)) or '(none: launch it with --placement)'}", file=sys.stderr)
            return EXIT_USAGE
        scenario = Scenario.from_dict(info["scenario"])
        procs = placement[group]
        forks = ForkServer.shared()
        for proc in procs:
            pids.append(forks.start(proc, node_process.main, ProcSpec(proc, scenario, info["layout"], endpoint, keys,
                                                                      security=security, settings=settings)))
        print(f"zenohedge-node: group {group}: started {len(procs)} processes of simulation {keys.sim_id} "
              f"({', '.join(procs[:6])}{' ...' if len(procs) > 6 else ''})", file=sys.stderr, flush=True)

        gone = threading.Event()
        transport.watch_tokens(keys.alive(ORCHESTRATOR), lambda key, alive: alive or gone.set())
        transport.dispatch(until=lambda: gone.is_set() or not forks.wait(pids, 0.0))
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
                    "elsewhere with `orchestrator launch SCENARIO --listen 0.0.0.0:PORT --placement FILE`.",
        epilog="See deploy/README.md.")
    add_sim_options(parser, required=True, connect_help="the orchestrator's router, e.g. tcp/10.0.0.1:7447",
                    sim_help="the simulation id (launch --sim-id fixes it)")
    parser.add_argument("--group", required=True, help="the group of the placement file this host runs")
    parser.add_argument("--timeout", type=float, default=30.0, help="seconds to wait for the orchestrator")
    add_security_options(parser, identity="group's",
                         config_help="a Zenoh JSON5 configuration file merged last into the configuration of this "
                                     "command's sessions and of the processes it starts (its settings win)")
    args = parser.parse_args(argv)
    try:
        security, settings = security_options(args)
    except SecurityError as exc:
        print(f"zenohedge-node: {exc}", file=sys.stderr)
        sys.exit(EXIT_USAGE)
    sys.exit(run_group(args.connect, Keys(args.sim, args.prefix), args.group, args.timeout, security, settings))


if __name__ == "__main__":
    main()
