"""Energy model (beyond the paper): dynamic compute, static idle, and radio transmission."""

from __future__ import annotations

from node_runtime.model.radio import dbm_to_watts


def compute_energy(kappa: float, cycles: float, frequency: float) -> float:
    """E = kappa * cycles * f^2 joules (CMOS dynamic power model)."""
    return kappa * cycles * frequency * frequency


def idle_energy(idle_power_w: float, dt: float) -> float:
    """Static power drawn every tick, busy or not."""
    return idle_power_w * dt


def transmit_energy(tx_power_dbm: float, seconds: float) -> float:
    """E = P_tx(W) * time on air."""
    return dbm_to_watts(tx_power_dbm) * seconds

