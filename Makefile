# swarmd developer targets. `make demo` and `make test` are the README's two commands.
# Everything installs into the checkout's own virtual environment (.venv), never into
# the interpreter on PATH: `make` leaves the system's Python untouched.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip
STAMP := .make-stamps

.PHONY: setup system-deps test lint demo demo-mavlink bench clean

$(STAMP)/system: scripts/system-deps.sh
	bash scripts/system-deps.sh
	mkdir -p $(STAMP) && touch $@

$(PY):
	$(PYTHON) -m venv $(VENV)

# uv installs what pip would, from the same index, in parallel: a fresh machine's setup
# takes a fraction of pip's time (cold caches, side by side on a loaded machine: 2.7 min
# against 10.5), which counts against the suite's 10 minutes in CI. `--native-tls` trusts
# the system's certificates, as pip does here (PIP_CERT). `--compile-bytecode` keeps
# pip's byte-compiling: where PYTHONDONTWRITEBYTECODE is set (this machine sets it), no
# import would cache its compiling, and every robot process would compile again
# (pymavlink's generated dialects most of all). Should uv be unavailable, pip does it.
# MAVProxy (the suite's ground station from ArduPilot, tests/test_mavproxy_vehicle.py) goes
# in without its declared OpenCV and VTK, some hundred MB a headless session never loads:
# its runtime needs only pymavlink, pyserial and numpy, which the dev extra brings.
UV := $(PY) -m uv pip install -q --native-tls --python $(PY) --compile-bytecode
$(STAMP)/python: pyproject.toml | $(PY)
	$(PIP) install -q 'uv>=0.5' && $(UV) -e '.[sim,ros2,dev]' \
	  || $(PIP) install -q -e '.[sim,ros2,dev]'
	$(UV) --no-deps 'MAVProxy>=1.8.75' || $(PIP) install -q --no-deps 'MAVProxy>=1.8.75'
	mkdir -p $(STAMP) && touch $@

setup: $(STAMP)/system $(STAMP)/python

system-deps: $(STAMP)/system

lint: $(STAMP)/python
	$(PY) -m ruff check .
	$(PY) -m mypy

# One worker per CPU and one more: the real-process modules spend most of their time
# waiting on their daemons (about a seventh of a core), and the extra worker keeps the
# cores busy meanwhile. `--dist loadfile` runs each module on one worker, so a module
# fixture (a wheel's venv, a flown run) is made once (docs/testing.md, "Parallel").
WORKERS := $(shell echo $$(( $$(nproc 2>/dev/null || echo 1) + 1 )))
# The checkout is installed editable, so nothing byte-compiles swarmd's own modules: where
# PYTHONDONTWRITEBYTECODE is set, every daemon the suite starts would compile them again
# (about 0.3 s of CPU per process). Compiled once here, as a wheel's install would be.
test: setup
	$(PY) -m compileall -q swarmd sim bench tests
	$(PY) -m pytest -q -n $(WORKERS) --dist loadfile

# The paper's swarm flown in MuJoCo, one process per robot; robot 2 crashes at 5 s and
# standby 6 flies over to f2's slot. out/demo/: summary, event log, timeline.png,
# trajectories.png, swarm.mp4 and key frames (a headless GL backend: system-deps).
demo: setup
	$(PY) -m swarmd.cli sim configs/paper.yaml --fault crash:2@5 --duration 15 --seed 1 \
	  --report out/demo

# The same swarm flown through MAVLink: each daemon talks to a simulated PX4 autopilot
# over loopback UDP; a motor fails on robot 2 at 5 s, its daemon hears it as MAVLink
# health and hands f2 over; standby 6 flies there. Report in out/demo-mavlink/.
demo-mavlink: setup
	$(PY) -m swarmd.cli sim configs/paper.yaml --link mavlink --autopilot px4 \
	  --fault motor:2@5 --duration 15 --seed 1 --report out/demo-mavlink

bench: setup
	for b in bench/bench_*.py; do echo "== $$b"; $(PY) $$b || exit 1; done

clean:
	rm -rf $(STAMP) $(VENV) out .pytest_cache .mypy_cache .ruff_cache
