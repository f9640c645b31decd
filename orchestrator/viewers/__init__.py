"""What people look at: the live monitor, run plots, topology drawings and the benchmark.

Viewers read the orchestrator's outputs and the bus; nothing in the orchestrator's core imports them.
"""
