"""Simulation of a whole swarm on one machine, in four packages whose imports point one way:

- `sim.shared`: what both simulators share: fault specs, the fold of who executes what,
  the invariant checker and the run summary.
- `sim.virtual`: the virtual-time simulator: every robot's core in one process on a
  virtual clock, with a seeded lossy network.
- `sim.physics`: MuJoCo quadrotors that fly the functions, and the pictures of a run.
- `sim.realtime`: the real-time swarm: one daemon process per robot on loopback, faults
  injected as signals and receive filters.
- `sim.xbee_emu`: software XBee radios (the real-time swarm's emulated radio medium).

`tests/test_layering.py` enforces the direction: shared <- virtual, physics <- realtime.
"""
