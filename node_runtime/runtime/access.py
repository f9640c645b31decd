"""Access control on the simulation's keys, enforced by the Zenoh routers (docs/bus.md, "Security"): the
orchestrator's, and the one ``zenohedge-node`` runs on each host for its processes.

With a security directory the router accepts only sessions whose TLS client certificate is signed by the
deployment's CA and whose login is in its ``users`` file. On top of that, this module writes the router's
``access_control`` section: which identity (certificate common name *and* login, both equal to the
identity's name, as ``deploy/make-certs.sh`` makes them) may send what, on which keys. Anything not
allowed is dropped by the router, silently for publications, with no answer for queries:

- ``orchestrator`` (the orchestrator's own node processes): everything;
- each placement group (login = group name): publishes only the ``Done`` and liveliness tokens of its
  own processes (on the clock's keys, or on its host's aggregator's and the group's ``…/clock/dones``
  key), mail to the inboxes those processes may send to, their broadcasts (states) and events of their
  own nodes; queries ``…/register/<group>`` for its own keys (origin.py);
- ``driver``: publishes ticks and per-tick metrics, queries ``…/control``, announces ``…/alive/driver/*``;
- ``monitor`` and everyone above: subscribes, watches tokens, queries ``…/session``.

Only ``orchestrator`` may declare a queryable (or reply): nobody else can answer ``…/session`` or
``…/control``, so a driver, a monitor and ``zenohedge-node`` hear the orchestrator's answers alone.

What the router cannot know stays with the orchestrator: that a ``Done`` comes from the process it names
(its MAC), and that a release of the clock comes from the driver that claimed it (its secret token).
"""

from __future__ import annotations

from typing import Any

from node_runtime.runtime.keys import Keys
from node_runtime.runtime.layout import ProcessLayout

ORCHESTRATOR, DRIVER, MONITOR = "orchestrator", "driver", "monitor"
IDENTITIES = (ORCHESTRATOR, DRIVER, MONITOR)
LOCAL_LINK = "unixsock-stream"  # how a host's processes reach its router
EVERY_MESSAGE = ["put", "delete", "declare_subscriber", "query", "reply", "declare_queryable", "liveliness_token",
                 "declare_liveliness_subscriber", "liveliness_query"]


def _rule(rule_id: str, messages: list[str], keys: list[str], flows: tuple[str, ...] = ("ingress",)) -> dict[str, Any]:
    return {"id": rule_id, "messages": messages, "flows": list(flows), "permission": "allow", "key_exprs": keys}


def _subject(name: str) -> dict[str, Any]:
    return {"id": name, "cert_common_names": [name], "usernames": [name]}


def group_keys(keys: Keys, plan: ProcessLayout, group: str, procs: list[str]) -> tuple[list[str], list[str]]:
    """What the processes of one group, and its host's aggregator, publish: (put keys, liveliness tokens)."""
    puts: dict[str, None] = {keys.dones(group): None}
    for proc in procs:
        puts[keys.done(proc)] = None
        puts[keys.host_done(group, proc)] = None
        puts.update(dict.fromkeys(keys.inbox(dst) for dst in plan.destinations(proc)))
        if plan.listeners[proc]:
            puts[keys.broadcasts(proc)] = None
        puts.update(dict.fromkeys(keys.events("*", node) for node in plan.node_of_proc(proc)))
    return list(puts), [keys.alive(proc) for proc in procs]


def _host_subject(name: str) -> dict[str, Any]:
    """On a host's router: the orchestrator is the router it joined, known by its TLS certificate (it does
    not log in here); everyone else comes over the local unix socket with a login and no certificate."""
    if name == ORCHESTRATOR:
        return {"id": name, "cert_common_names": [name]}
    return {"id": name, "usernames": [name], "link_protocols": [LOCAL_LINK]}


def access_control(keys: Keys, plan: ProcessLayout, placement: dict[str, list[str]],
                   on_host: bool = False) -> dict[str, Any]:
    """The router's ``access_control`` configuration section for this simulation and placement.

    ``on_host``: for the router ``zenohedge-node`` runs on a host, which holds its processes to the same
    rules, so that a session there cannot forge to its neighbours what the orchestrator's router refuses."""
    reading = [
        _rule("read", ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"],
              [f"{keys.prefix}/**"]),
        _rule("describe", ["query"], [f"{keys.prefix}/*/session"]),
        _rule("receive", EVERY_MESSAGE, [f"{keys.prefix}/**"], ("egress",)),
    ]
    rules = [
        _rule("all", EVERY_MESSAGE, ["**"], ("ingress", "egress")),
        *reading,
        _rule("drive", ["put"], [keys.tick(), keys.tick("*"), keys.metrics()]),
        _rule("drive-control", ["query"], [keys.control()]),
        _rule("drive-token", ["liveliness_token"], [keys.alive("driver/*")]),
    ]
    read = [r["id"] for r in reading]
    policies = [
        {"id": ORCHESTRATOR, "rules": ["all"], "subjects": [ORCHESTRATOR]},
        {"id": DRIVER, "rules": [*read, "drive", "drive-control", "drive-token"], "subjects": [DRIVER]},
        {"id": MONITOR, "rules": read, "subjects": [MONITOR]},
    ]
    for group, procs in placement.items():
        puts, tokens = group_keys(keys, plan, group, procs)
        rules += [_rule(f"group-{group}-put", ["put"], puts),
                  _rule(f"group-{group}-token", ["liveliness_token"], tokens),
                  _rule(f"group-{group}-register", ["query"], [keys.register(group)])]
        policies.append({"id": f"group-{group}", "rules": [*read, f"group-{group}-put", f"group-{group}-token",
                                                          f"group-{group}-register"], "subjects": [group]})
    subjects = [(_host_subject if on_host else _subject)(name) for name in (*IDENTITIES, *placement)]
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}
