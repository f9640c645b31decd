"""The runtime: the model's roles hosted in processes and connected over a bus.

``transport`` is the bus interface, with ``zenoh_bus`` and ``inproc`` behind it; ``codec`` and
``protocol`` are the wire; ``layout`` maps roles to processes; ``host`` and ``driver`` run one
process's roles each tick; ``process``, ``forkserver`` and ``remote`` start node processes.
"""
