"""Print one line per tick and per dropped task of a running ZenohEdge simulation (docs/bus.md).

    python examples/subscriber.py ENDPOINT SIM_ID [PREFIX]      # e.g. tcp/127.0.0.1:7447 1a2b3c4d

Needs only eclipse-zenoh and msgpack. It only subscribes, so the simulation runs exactly as without it.
"""

import json
import os
import queue
import sys

import msgpack
import zenoh

endpoint, sim = sys.argv[1], sys.argv[2]
root = f"{sys.argv[3] if len(sys.argv) > 3 else 'zedge'}/{sim}"
config = zenoh.Config()
config.insert_json5("mode", '"client"')  # a client of the orchestrator's router
config.insert_json5("connect/endpoints", json.dumps([endpoint]))
config.insert_json5("scouting/multicast/enabled", "false")
samples: queue.SimpleQueue = queue.SimpleQueue()  # Zenoh calls back on its threads: print from this one
with zenoh.open(config) as session:
    subscribers = [session.declare_subscriber(f"{root}/metrics/tick", samples.put),
                   session.declare_subscriber(f"{root}/events/dropped/*", samples.put)]
    try:
        while True:
            m = msgpack.unpackb(samples.get().payload.to_bytes())
            if m["type"] == "metrics":
                t = m["totals"]
                print(f"tick {m['tick']}: generated {t['generated']} completed {t['completed']} "
                      f"dropped {sum(t['dropped'].values())} in system {t['in_system']}", flush=True)
            else:
                print(f"  dropped task {m['task']} at {m['node']} in tick {m['tick']}: {m['cause']}", flush=True)
    except KeyboardInterrupt:
        pass
    except BrokenPipeError:  # `| head` has read enough: leave quietly, as Unix filters do
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
