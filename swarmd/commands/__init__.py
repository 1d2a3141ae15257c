"""CLI commands, one module each; every module exposes `register(app)`.

`swarmd.cli` imports every command module at start, so a module keeps its heavy imports
(MuJoCo, digi-xbee, matplotlib) inside the command function: `swarmd --help` stays fast.
"""
