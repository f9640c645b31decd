"""The system model: what a node does each tick, with no transport anywhere below it.

Roles (``worker``, ``client``, ``controller``) are deterministic functions of their state, the tick
and their inbox; they send through an ``Outbox`` and never know how mail travels.
"""
