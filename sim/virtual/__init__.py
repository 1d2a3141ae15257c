"""The virtual-time simulator: the same core as the daemon, every robot in one process on
a virtual clock (deterministic by seed, far faster than real time)."""
