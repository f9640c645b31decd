"""The orchestrator: owns the simulated clock, launches and supervises node processes, gathers metrics."""
