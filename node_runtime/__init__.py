"""The node side of the emulator, in two layers.

- ``node_runtime.model``: the system model (tasks, workers, clients, controllers, links, energy,
  workloads, policies). Pure Python: it runs and tests with no bus at all.
- ``node_runtime.runtime``: what carries the model over a bus (codec, clock protocol, transports,
  hosts, node processes). It imports the model; the model never imports it.

The classes a user extends (docs/extending.md) are importable from here.
"""

from node_runtime.model.client import Client
from node_runtime.model.controller import Controller
from node_runtime.model.policies import Policy
from node_runtime.model.role import Role
from node_runtime.model.worker import Worker
from node_runtime.model.workload import TaskSource

__all__ = ["Client", "Controller", "Policy", "Role", "TaskSource", "Worker"]
