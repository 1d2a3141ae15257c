"""Shared fixtures: the paper's swarm plan and parameters, and hypothesis profiles.

Profiles: "ci" (the default here: a few hundred examples of the random-schedule
property, no deadline because example cost depends on the drawn swarm) and "bench"
(thousands; `HYPOTHESIS_PROFILE=bench pytest tests/test_properties.py`).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

from sim.realtime.ports import PortLease
from swarmd.base.logs import JsonFormatter, TextFormatter
from swarmd.config import load_swarm
from swarmd.core.params import Params
from swarmd.core.plan import SwarmPlan

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = ROOT / "configs"

settings.register_profile("ci", deadline=None, derandomize=True,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("dev", deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("bench", deadline=None, max_examples=5000,
                          suppress_health_check=[HealthCheck.too_slow])
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


@pytest.fixture(scope="session")
def paper() -> tuple[SwarmPlan, Params]:
    """configs/paper.yaml: 1-4 active in a ring, 5 covers f1/f4, 6 covers f2/f3."""
    cfg = load_swarm(CONFIGS / "paper.yaml")
    return cfg.to_plan(), cfg.params()


@pytest.fixture(scope="session")
def paper_plan(paper: tuple[SwarmPlan, Params]) -> SwarmPlan:
    return paper[0]


@pytest.fixture(scope="session")
def udp_params(paper: tuple[SwarmPlan, Params]) -> Params:
    return paper[1]


@pytest.fixture
def udp_port() -> Iterator[int]:
    """A multicast port of this test's own, held until the test ends: daemons of tests
    running at the same time (pytest -n) never hear each other (sim/realtime/ports.py)."""
    with PortLease() as lease:
        yield lease.port


@pytest.fixture(autouse=True)
def _own_ros_domains(monkeypatch: pytest.MonkeyPatch) -> None:
    """`swarmd sim --link ros2` runs in $ROS_DOMAIN_ID when it is set: a developer's
    shell that exports one would put every test's swarm in it, where they hear each
    other. Tests lease their own domains (`DomainLease`) or pass one explicitly."""
    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)


@pytest.fixture(autouse=True)
def _swarmd_log_handlers_removed() -> Iterator[None]:
    """A test that runs `swarmd start` in-process (CliRunner) leaves the root logger writing
    to that run's captured stdout (`setup_logging`), closed once the run returns; a later
    test in the same worker whose code logs then prints `--- Logging error ---` with a
    traceback into its own captured output. Which tests share a worker depends on the
    xdist split, so each test ends with swarmd's own handlers removed, and any handler
    left writing to a closed stream."""
    yield
    root = logging.getLogger()
    for h in list(root.handlers):
        dead = isinstance(h, logging.StreamHandler) and getattr(h.stream, "closed", False)
        if dead or isinstance(h.formatter, JsonFormatter | TextFormatter):
            root.removeHandler(h)
