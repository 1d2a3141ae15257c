"""The real-time swarm: one daemon process per robot over loopback multicast or emulated
radios, faults injected as signals and receive filters, a live view and the run's log."""
