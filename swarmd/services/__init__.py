"""The services room: what the daemon is built from (DESIGN section 1, "Layout").

The asyncio owner of one core node (`runtime`), the robot's persisted epochs and
sequence reservation (`state`), Prometheus metrics (`metrics`), the channel budget
(`budget`), the paper's launch-file import (`launch`) and what a revoked robot does
(`revocation`). It imports the core, the base, the transports, the links and the config
files, and nothing of the daemon or the commands above it.
"""
