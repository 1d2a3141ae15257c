"""Simulation: the virtual-time swarm simulator, the multi-process real-time swarm,
MuJoCo quadrotors, rendering and reports."""
