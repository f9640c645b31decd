"""Key expressions: everything of one simulation lives under ``{prefix}/{sim_id}/`` (docs/bus.md, "Key layout")."""

from __future__ import annotations

import re
import secrets
from dataclasses import dataclass

DEFAULT_PREFIX = "zedge"
CHUNK = re.compile(r"^[A-Za-z0-9_.\-]+$")  # a key chunk without wildcards or separators


def new_sim_id() -> str:
    return secrets.token_hex(4)


@dataclass(frozen=True)
class Keys:
    sim_id: str
    prefix: str = DEFAULT_PREFIX

    @property
    def root(self) -> str:
        return f"{self.prefix}/{self.sim_id}"

    def tick(self, proc: str | None = None) -> str:
        """The tick for every process (reset, stop, or a tick all take part in), or for one."""
        return f"{self.root}/clock/tick" if proc is None else f"{self.root}/clock/tick/{proc}"

    def done(self, proc: str = "*") -> str:
        return f"{self.root}/clock/done/{proc}"

    def host_done(self, group: str, proc: str = "*") -> str:
        """A process's ``Done`` to its host's aggregator, when ``zenohedge-node`` runs one (docs/protocol.md)."""
        return f"{self.root}/host/{group}/done/{proc}"

    def dones(self, group: str = "*") -> str:
        """One host's ``Done`` reports of a tick, in one message."""
        return f"{self.root}/clock/dones/{group}"

    def inbox(self, proc: str) -> str:
        return f"{self.root}/proc/{proc}/inbox"

    def broadcasts(self, proc: str) -> str:
        """One process's broadcasts (its workers' states): every tick's in one batch."""
        return f"{self.root}/proc/{proc}/broadcast"

    def alive(self, proc: str = "*") -> str:
        return f"{self.root}/alive/{proc}"

    def metrics(self) -> str:
        return f"{self.root}/metrics/tick"

    def events(self, kind: str = "*", node: str = "*") -> str:
        return f"{self.root}/events/{kind}/{node}"

    def session(self) -> str:
        """Queryable: what a remote driver or monitor needs to know about the simulation."""
        return f"{self.root}/session"

    def register(self, group: str) -> str:
        """Queryable: a host's keys (origin.py), for the host that runs ``group``."""
        return f"{self.root}/register/{group}"

    def control(self) -> str:
        """Queryable: claim or release the clock (attach mode)."""
        return f"{self.root}/control"
