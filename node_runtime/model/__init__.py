"""The system model: what a node does each tick, with no transport anywhere below it.

Roles (``worker``, ``client``, ``controller``) are deterministic functions of their state, the tick
and their inbox; they send through an ``Outbox`` and never know how mail travels.

Role kinds register themselves when their module is imported (``registry``); importing the built-in
ones here registers them whichever module of the model a program imports first.
"""

from node_runtime.model import client, controller, worker  # noqa: F401
