"""Proof of origin: secret keys, and the MACs that prove who sent a tick or a report (docs/security.md).

Anyone who reaches a simulation's router can publish a well-formed message on any key. What the bus cannot
fake is a key it never carried: the orchestrator draws one key per process, one per host (placement group)
and one for the clock (``Keyring.new``), and hands each party its own out of band: a local process gets its
key and the clock's in its start request (through the fork server's pipe), a host gets its group's when it
registers (``…/register/<group>``, a query answered to the asker alone: over TLS, and to the group's identity
only, with ``--security``).

Every ``Tick``, ``Done`` and ``Dones`` carries ``mac``: keyed BLAKE2b over the message as it travels (its
encoded bytes over Zenoh; in one process, where messages are objects that never leave its memory, over the
fields that say who sent it for which tick, ``identity``). The keys a message is sealed with belong to one
*epoch* of the clock (``derive``): a driver that claims the clock gets the keys of its epoch only, so that
once its claim ends it can no longer tick nor report to whoever holds the clock next.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
from dataclasses import dataclass, field
from typing import Any

KEY_BYTES = 32
MAC_BYTES = 16
CLOCK = "clock"  # what the clock's key is called in a grant


def new_key() -> bytes:
    return secrets.token_bytes(KEY_BYTES)


def derive(key: bytes, epoch: int) -> bytes:
    """The key of one epoch of the clock, from a party's own key."""
    return hashlib.blake2b(epoch.to_bytes(8, "big", signed=True), key=key, digest_size=KEY_BYTES,
                           person=b"zenohedge-epoch").digest()


def mac(key: bytes, data: bytes) -> bytes:
    return hashlib.blake2b(data, key=key, digest_size=MAC_BYTES).digest()


def identity(msg: Any) -> bytes:
    """What a MAC covers in one process: the kind, epoch, episode, tick and sender (or command) of a tick or a
    report; for a host's reports, the group and each report's."""
    kind = type(msg).__name__
    dones = getattr(msg, "dones", None)
    if dones is not None:
        return f"{kind}|{msg.epoch}|{msg.group}|{','.join(f'{d.proc}:{d.episode}:{d.tick}' for d in dones)}".encode()
    return f"{kind}|{msg.epoch}|{msg.episode}|{msg.tick}|{getattr(msg, 'proc', None) or msg.command}".encode()


def seal(msg: Any, key: bytes) -> None:
    """Seal a message that travels as an object (the in-process bus): ``signed`` and ``mac`` over ``identity``."""
    msg.signed = identity(msg)
    msg.mac = mac(key, msg.signed)


def authentic(key: bytes | None, msg: Any) -> bool:
    """Whether ``msg`` carries the MAC of ``key`` over what it was sealed over."""
    return key is not None and msg.mac is not None and hmac.compare_digest(mac(key, msg.signed), msg.mac)


@dataclass(frozen=True)
class Keyring:
    """The keys one party holds. Own keys (``epoch`` None) give the key of any epoch; a driver's grant holds
    those of its epoch only. A node process holds the clock's and its own; a host's aggregator the clock's,
    its processes' and its own; the orchestrator every key."""

    clock: bytes
    procs: dict[str, bytes] = field(default_factory=dict)
    hosts: dict[str, bytes] = field(default_factory=dict)
    epoch: int | None = None  # the only epoch these keys are of, or None: own keys, of every epoch
    _derived: dict[tuple[str, str, int], bytes] = field(default_factory=dict, compare=False, repr=False)

    @classmethod
    def new(cls, procs: list[str] | tuple[str, ...], groups: list[str] | tuple[str, ...] = ()) -> Keyring:
        return cls(new_key(), {p: new_key() for p in procs}, {g: new_key() for g in groups})

    def _key(self, kind: str, name: str, own: bytes | None, epoch: int) -> bytes | None:
        if own is None:
            return None
        if self.epoch is not None:
            return own if epoch == self.epoch else None
        slot = (kind, name, epoch)
        key = self._derived.get(slot)
        if key is None:
            key = self._derived[slot] = derive(own, epoch)
        return key

    def clock_key(self, epoch: int) -> bytes | None:
        return self._key(CLOCK, "", self.clock, epoch)

    def proc_key(self, proc: str, epoch: int) -> bytes | None:
        return self._key("proc", proc, self.procs.get(proc), epoch)

    def host_key(self, group: str, epoch: int) -> bytes | None:
        return self._key("host", group, self.hosts.get(group), epoch)

    def of(self, procs: list[str] | tuple[str, ...], group: str | None = None) -> Keyring:
        """The own keys of some processes (and of their host), with the clock's: what a node process or a host gets."""
        return Keyring(self.clock, {p: self.procs[p] for p in procs},
                       {group: self.hosts[group]} if group is not None else {})

    def grant(self, epoch: int) -> dict[str, Any]:
        """The keys of one epoch, for the driver that holds the clock in it (a reply to its claim)."""
        return {"epoch": epoch, CLOCK: self.clock_key(epoch),
                "procs": {p: self.proc_key(p, epoch) for p in self.procs},
                "hosts": {g: self.host_key(g, epoch) for g in self.hosts}}

    @classmethod
    def granted(cls, grant: dict[str, Any]) -> Keyring:
        return cls(grant[CLOCK], dict(grant["procs"]), dict(grant["hosts"]), grant["epoch"])

    def to_wire(self) -> dict[str, Any]:
        """Own keys, for a host's registration answer."""
        return {CLOCK: self.clock, "procs": self.procs, "hosts": self.hosts}

    @classmethod
    def from_wire(cls, d: dict[str, Any]) -> Keyring:
        return cls(d[CLOCK], dict(d["procs"]), dict(d["hosts"]))
