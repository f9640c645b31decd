"""Messages refused on the bus: counted by reason, logged at a bounded rate (docs/bus.md, "Rejected messages").

Anyone who reaches a simulation's router can publish on its keys. Decoders and protocol handlers
refuse what they cannot decode or trust rather than crash or let it change a result, and record it
here. Recording happens only for refused messages, so the hot path pays nothing for it.
"""

from __future__ import annotations

import logging
import os
import threading
import time

# Why a message was refused: the keys of the counts in summary.json and of the log lines.
BAD_MSGPACK = "bad_msgpack"  # not msgpack at all
SCHEMA_VERSION = "schema_version"  # no schema version, or another one (another ZenohEdge version)
WRONG_SHAPE = "wrong_shape"  # not a map, a missing field or one of the wrong type, or a message not meant for the key
UNKNOWN_SENDER = "unknown_sender"  # a process or role that is not of this layout, or that may not send this
WRONG_TICK = "wrong_tick"  # an episode or tick that is not the current one, a duplicate, or too late
CLOCK_TAKEN = "clock_taken"  # a claim of the clock while a driver holds it, or while the orchestrator keeps it
NOT_HOLDER = "not_holder"  # a release of the clock without the name and token of the driver that holds it
BAD_MAC = "bad_mac"  # a tick or report without the MAC of the sender it names (origin.py): a forgery
STALE_EPOCH = "stale_epoch"  # a tick, report or release of a holder of the clock whose epoch is over
TOO_LARGE = "too_large"  # a payload larger than its kind of message may be (limits.py)
SEVERAL_ANSWERS = "several_answers"  # answers to one request from more than one session: none is believed
REASONS = (BAD_MSGPACK, SCHEMA_VERSION, WRONG_SHAPE, UNKNOWN_SENDER, WRONG_TICK, CLOCK_TAKEN, NOT_HOLDER, BAD_MAC,
           STALE_EPOCH, TOO_LARGE, SEVERAL_ANSWERS)

LOG_INTERVAL = 10.0  # seconds: at most one line per key in this interval
MAX_KEYS = 256  # keys tracked one by one; past that, further keys share one line (senders choose keys)
OTHER_KEYS = "(other keys)"
LONGEST = 200  # characters of a key or a reason in a log line: both may come from the sender

log = logging.getLogger("zenohedge.bus")


class Rejections:
    """Counts of refused messages by reason, and their rate-limited log.

    ``who`` names the refusing side in log lines: a node process's name, "orchestrator", a driver's
    name (the default names the OS process). ``changed`` tells a node process to put its counts in its
    next ``Done``. Safe to call from Zenoh's threads too.
    """

    def __init__(self, who: str | None = None, interval: float = LOG_INTERVAL) -> None:
        self.who = who or f"process {os.getpid()}"
        self.interval = interval
        self.counts: dict[str, int] = {}
        self.changed = False
        self.last: dict[str, str] = {}  # key -> why its latest refused message was refused
        self._logged: dict[str, tuple[float, int]] = {}  # key -> (time of its last line, refused since)
        self._lock = threading.Lock()

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def add(self, key: str, reason: str, why: str) -> None:
        why = why.replace("\n", " ")[:LONGEST]
        with self._lock:
            self.counts[reason] = self.counts.get(reason, 0) + 1
            self.changed = True
            slot = key if key in self._logged or len(self._logged) < MAX_KEYS else OTHER_KEYS
            self.last[slot] = f"{reason} ({why})"
            now = time.monotonic()
            at, since = self._logged.get(slot, (-self.interval, 0))
            if now - at < self.interval:
                self._logged[slot] = (at, since + 1)
                return
            self._logged[slot] = (now, 0)
        more = f" [+{since} more on this key since the last line]" if since else ""
        log.warning("zenohedge: %s rejected a message on %s: %s (%s)%s", self.who, key[:LONGEST],
                    reason, why, more)

    def line(self) -> str:
        """The counts as 'bad_msgpack 2, wrong_tick 1' (for a closing log line)."""
        return ", ".join(f"{reason} {n}" for reason, n in sorted(self.counts.items()))

    def log_total(self) -> None:
        """The closing log line of a process that refused anything: how many messages, for which reasons."""
        if self.total:
            log.warning("zenohedge: %s rejected %d messages in all: %s", self.who, self.total, self.line())
