"""An outsider for tests/test_deploy.py: tries to join a simulation's router and, if it gets in, forges
a ``stop`` tick, ``Done`` messages of a victim process (alone, and as its host's aggregator would send them)
and a release of the clock, over and over, until
the orchestrator's liveliness token vanishes.

    python -m tests.intruder ENDPOINT SIM VICTIM [--security DIR] [--ca FILE] [--password P]

Prints ``refused`` (exit 3) when the session cannot open, else ``connected``, ``forging`` once its first
round is out, and at the end ``forged N``, the number of rounds it published.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import threading

from node_runtime.runtime import codec
from node_runtime.runtime.keys import Keys
from node_runtime.runtime.process import ORCHESTRATOR
from node_runtime.runtime.protocol import Done, Dones, Tick
from node_runtime.runtime.security import Security
from node_runtime.runtime.zenoh_bus import ZenohTransport

ROUND_S = 0.02
LIMIT_S = 300.0


def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("endpoint")
    parser.add_argument("sim")
    parser.add_argument("victim")
    parser.add_argument("--victim-group", default="cluster-b", help="the placement group the victim runs in")
    parser.add_argument("--security", help="an identity directory (a stolen or compromised host's)")
    parser.add_argument("--ca", help="TLS checking the router against this CA, without a client certificate")
    parser.add_argument("--password", help="replace the identity's password")
    args = parser.parse_args()
    security = Security.from_dir(args.security) if args.security else None
    if security is not None and args.password:
        security = dataclasses.replace(security, password=args.password)
    settings = {"transport/link/tls/root_ca_certificate": args.ca} if args.ca else None
    try:
        transport = ZenohTransport.client(args.endpoint, security, settings)
    except Exception:
        print("refused", flush=True)
        return 3
    print("connected", flush=True)
    keys = Keys(args.sim)
    gone = threading.Event()
    transport.watch_tokens(keys.alive(ORCHESTRATOR), lambda key, alive: alive or gone.set())
    session = transport.session
    rounds = 0
    while True:
        try:
            transport.dispatch(until=gone.is_set, timeout=ROUND_S)
            break
        except TimeoutError:  # a round of forgeries between two looks at the orchestrator's token
            for tick in range(rounds, rounds + 3):
                session.put(keys.tick(), codec.encode(Tick(0, tick, "stop")))
                forged = Done(args.victim, 0, tick, {}, {})
                session.put(keys.done(args.victim), codec.encode(forged))
                session.put(keys.host_done(args.victim_group, args.victim), codec.encode(forged))
                session.put(keys.dones(args.victim_group), codec.encode(Dones(args.victim_group, [forged])))
            session.get(keys.control(), payload=codec.encode(
                {"type": "control", "release": "driver/x", "episode": 9}), timeout=0.1)
            rounds += 1
            if rounds == 1:
                print("forging", flush=True)
            if rounds * ROUND_S > LIMIT_S:
                break
    print(f"forged {rounds}", flush=True)
    transport.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
