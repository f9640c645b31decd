"""How big a message may be (docs/bus.md, "Limits"): anyone who reaches a router can publish, and a
small msgpack payload can decode into gigabytes (a 50 MB array of empty maps is 50 million dicts).

Three bounds, from the outside in:

- ``LINK_MAX``: Zenoh's own ``transport/link/rx/max_message_size``, set on every router and session
  ZenohEdge opens. Zenoh drops a larger message while it reassembles it, in the router it reaches first
  and in the receiving process, before Python sees a byte of it (so it cannot be counted);
- ``payload_limit``: the largest payload of each kind of message, told by its key. A larger one is
  refused before it is copied out of Zenoh or decoded, and counted as ``too_large``. msgpack is told the
  same bound for every string and array it decodes. Every decoded item takes at least one byte of
  payload, so the limit also bounds the items a message decodes into: at worst (empty maps) about 72
  bytes of memory per byte of payload, briefly;
- ``QUEUE_BYTES``: the undecoded bytes a process holds for its dispatch thread. Past it, Zenoh's
  network thread waits until dispatch catches up: back-pressure up to the publisher, which blocks
  (protocol messages are reliable and blocking), so nothing is dropped. Zenoh closes a link blocked for
  longer than its ``wait_before_close``, which follows the lease (zenoh_bus.zenoh_config).

The limits are constants, not derived from the scenario: what a message carries grows with the tasks in
flight, which the model does not bound (arrivals are random, queues are unbounded). They leave a wide
margin over the largest messages measured (docs/bus.md, "Limits").
"""

from __future__ import annotations

KIB = 1024
MIB = 1024 * KIB

LINK_MAX = 8 * MIB  # Zenoh drops larger messages inside the router and the receiving session
QUEUE_BYTES = 16 * MIB  # received bytes waiting for dispatch, past which Zenoh's receiving thread waits

# kind -> the largest payload in bytes; the kind of a key is the chunk after the simulation's root
# (clock/tick, clock/done, clock/dones, host/<group>/done, proc/<p>/inbox, ...)
TICK, MAIL, REPORT, REPORTS, OTHER = "tick", "mail", "report", "reports", "other"
LIMITS = {TICK: 256 * KIB, MAIL: 1 * MIB, REPORT: 1 * MIB, REPORTS: 4 * MIB, OTHER: 1 * MIB}


def kind_of(key: str) -> str:
    """The kind of message a key (or a subscription's key expression) carries: ``{prefix}/{sim}/...``."""
    chunks = key.split("/")
    area, what = (chunks[2], chunks[3]) if len(chunks) > 3 else ("", "")
    if area == "clock":
        return {"tick": TICK, "done": REPORT, "dones": REPORTS}.get(what, OTHER)
    if area == "host":  # host/<group>/done/<proc>: a process's Done to its host's aggregator
        return REPORT
    if area == "proc":  # proc/<p>/inbox and proc/<p>/broadcast: batches of mail
        return MAIL
    return OTHER  # session and control requests and answers, metrics and events for monitors


def payload_limit(key: str) -> int:
    return LIMITS[kind_of(key)]
