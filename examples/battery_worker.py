"""A worker with a battery: it refuses new tasks while depleted (docs/extending.md, example 1).

Named in a scenario as ``roles: {worker: battery_worker:BatteryWorker}``; configured per node or
profile with ``params``: battery_j (capacity, starts full), harvest_w (recharge), busy_w (drain while
the CPU works), reserve_j (below it, new tasks are refused).
"""

from node_runtime import Worker


class BatteryWorker(Worker):
    def reset(self, seed):
        super().reset(seed)
        self.capacity_j = float(self.node.param("battery_j", 200.0))
        self.harvest_w = float(self.node.param("harvest_w", 0.5))
        self.busy_w = float(self.node.param("busy_w", 3.0))
        self.reserve_j = float(self.node.param("reserve_j", 20.0))
        self.charge_j = self.capacity_j

    def admit(self, t, arrivals, out):
        if self.charge_j < self.reserve_j:  # depleted: refuse, exactly as a full buffer would
            for task in arrivals:
                self.drop(out, "queue_full", task.id)
            return
        super().admit(t, arrivals, out)

    def serve(self, t, out):
        if self.charge_j > 0.0:  # an empty battery stops the CPU
            super().serve(t, out)

    def tick(self, t, inbox, out):
        busy, sent = self.stats.busy_cycles, self.stats.energy_transmit
        was_low = self.charge_j < self.reserve_j
        super().tick(t, inbox, out)
        busy_s = (self.stats.busy_cycles - busy) / self.node.capacity
        used = self.busy_w * busy_s + (self.stats.energy_transmit - sent)
        self.charge_j = min(self.capacity_j, max(0.0, self.charge_j - used + self.harvest_w * self.dt))
        if (self.charge_j < self.reserve_j) != was_low:  # a monitoring event: …/events/battery/<node>
            out.emit("battery", self.node.id, charge_j=self.charge_j, depleted=not was_low)
