"""Cameras that classify only what moves: a task source that gives each task its type (docs/extending.md).

Frames arrive as the built-in count says (Poisson at the scenario's rate). A frame taken while something
moves in front of the camera, the first ``motion_s`` seconds of every ``period_s`` (node params), is a task
of type ``classify``, whose payload, the numpy classifier, really runs; any other frame is a ``check``, a
small task of its nominal size.
"""

from node_runtime.model.workload import TaskSource


class MotionCamera(TaskSource):
    def __init__(self, scenario, node, counts_rng, types_rng):
        spec = scenario.node[node]
        self.period = float(spec.param("period_s", 20.0))
        self.motion = float(spec.param("motion_s", 5.0))
        super().__init__(scenario, node, counts_rng, types_rng)
        names = [t.name for t in self.types]
        self.classify, self.check = names.index("classify"), names.index("check")

    def typed(self, tick):
        kind = self.classify if (tick * self.dt) % self.period < self.motion else self.check
        task_type = self.types[kind]
        return [(task_type.size(task_type.draw_deadline(self.deadlines_rng)), kind) for _ in range(self.count(tick))]

    # its tasks come in the ticks the built-in count gives them: look ahead as the built-in source does
    next_arrival = TaskSource.next_arrival
