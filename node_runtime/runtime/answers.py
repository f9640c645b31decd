"""The shapes of the answers on ``…/session`` and ``…/control`` (docs/bus.md), checked where they are read.

A driver, a monitor and ``zenohedge-node`` act on these answers: the scenario they run, the episode they
number theirs after, whether they hold the clock. The transport already refuses answers when a second
session answers the same key (``Transport.request``); what is left is an answer of the wrong shape, from
another ZenohEdge version or from whoever alone answers for a simulation id. It gets one ``AnswerError``
that says which field is wrong, never a KeyError or a validation trace from deep inside.
"""

from __future__ import annotations

import re
from typing import Any

from pydantic import ValidationError

from node_runtime.model.spec import Scenario
from node_runtime.runtime.layout import check_layout
from node_runtime.runtime.origin import CLOCK, KEY_BYTES

EPISODES = 2**31  # episode numbers run from -1 (none yet) below this, as ticks do
TOKEN = re.compile(r"^[0-9a-f]{32}$")  # serve.py's secrets.token_hex(16)


class AnswerError(ValueError):
    pass


def _is_str(x: Any) -> bool:
    return type(x) is str


def _episode(x: Any) -> bool:
    return type(x) is int and -1 <= x < EPISODES


def _str_lists(m: Any) -> bool:
    return type(m) is dict and all(_is_str(k) and type(v) is list and all(map(_is_str, v)) for k, v in m.items())


def _key(k: Any) -> bool:
    return type(k) is bytes and len(k) == KEY_BYTES


def _epoch_keys(grant: Any) -> bool:
    """A grant's keys (origin.Keyring.grant): its epoch, the clock's key, and every process's and host's."""
    return (type(grant) is dict and type(grant.get("epoch")) is int and _key(grant.get(CLOCK))
            and all(type(m) is dict and all(_is_str(n) and _key(k) for n, k in m.items())
                    for m in (grant.get("procs"), grant.get("hosts"))))


def session_answer(info: Any, key: str) -> dict[str, Any]:
    """``info`` if it is a session description of the documented shape, with a scenario that validates."""
    def wrong(what: str) -> AnswerError:
        return AnswerError(f"{key} answered {what}: is it another ZenohEdge version, or not a ZenohEdge simulation?")

    if type(info) is not dict or info.get("type") != "session":
        raise wrong("something that is not a session description")
    fields = (("sim", _is_str), ("scenario", lambda x: type(x) is dict), ("layout", _is_str), ("episode", _episode),
              ("driver", lambda x: x is None or _is_str(x)),
              ("procs", lambda x: type(x) is list and all(map(_is_str, x))), ("placement", _str_lists))
    for name, ok in fields:
        if name not in info or not ok(info[name]):
            raise wrong(f"a session description whose field {name!r} is missing or not of the documented shape")
    if info["sim"] != key.split("/")[-2]:  # {prefix}/{sim}/session
        raise wrong(f"the session description of simulation {info['sim'][:40]!r}")
    for name in ("ready_timeout", "lease_s"):  # only a simulation served over Zenoh gives them
        if name in info and not (type(info[name]) in (int, float) and 0 < info[name] < float("inf")):
            raise wrong(f"a session description whose field {name!r} is not a positive number")
    try:
        check_layout(info["layout"])
        Scenario.from_dict(info["scenario"])
    except (ValueError, TypeError, KeyError, ValidationError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise wrong(f"a session description whose scenario or layout does not validate ({first})") from None
    return info


def claim_answer(answer: Any, key: str, seen: int) -> dict[str, Any]:
    """``answer`` if it is the answer to a claim: refused with a reason, or granted with a token, the keys of its
    epoch and the latest episode, which is never below ``seen``, the episode the session description gave
    before the claim (episode numbers only grow)."""
    def wrong(what: str) -> AnswerError:
        return AnswerError(f"{key} answered the claim with {what}")

    if type(answer) is not dict or answer.get("type") != "control" or type(answer.get("granted")) is not bool:
        raise wrong("something that is neither a grant nor a refusal")
    if not answer["granted"]:
        if type(answer.get("reason", "")) is not str:
            raise wrong("a refusal whose reason is not text")
        return answer
    if not (type(answer.get("token")) is str and TOKEN.match(answer["token"])):
        raise wrong("a grant without a token of 32 hexadecimal digits")
    if not _epoch_keys(answer.get("keys")):
        raise wrong("a grant without the keys of its epoch")
    if not (_episode(answer.get("episode")) and answer["episode"] >= seen):
        raise wrong(f"a grant at episode {answer.get('episode')!r}, where the session said {seen}: episode numbers "
                    "only grow")
    return answer
