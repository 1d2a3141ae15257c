"""The base room: what every room above the core shares (DESIGN section 1, "Layout").

Bounded file reads and atomic private writes (`files`), swarm keys and per-robot
identities (`keys`, `identity`), what a function means to fly (`functions`), the daemon's
logs, readiness notification and event log (`logs`, `notify`, `eventlog`), signals during
start-up (`signals`) and the signature-checking budget (`verify_budget`). It imports only
`swarmd.core`; nothing here knows a transport, a link or the config files.
"""
