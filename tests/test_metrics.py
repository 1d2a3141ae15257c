"""swarmd.services.metrics: what the runtime records, scraped over real HTTP from loopback."""

from __future__ import annotations

from collections.abc import Iterator

import httpx
import pytest
from prometheus_client.parser import text_string_to_metric_families

from swarmd.core import events as ev
from swarmd.core.actions import Assign, Broadcast
from swarmd.core.node import Snapshot
from swarmd.core.roles import Health, Role
from swarmd.services.metrics import Metrics, MetricsError, MetricsServer, check_loopback


def _samples(text: str) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    out = {}
    for family in text_string_to_metric_families(text):
        for s in family.samples:
            out[(s.name, tuple(sorted(s.labels.items())))] = s.value
    return out


@pytest.fixture
def served() -> Iterator[tuple[Metrics, MetricsServer]]:
    metrics = Metrics(robot_id=5, swarm_id=1543)
    server = metrics.start_server("127.0.0.1", 0)
    yield metrics, server
    server.close()


def test_endpoint_serves_what_the_runtime_recorded(served: tuple[Metrics, MetricsServer]) -> None:
    metrics, server = served
    metrics.frame_sent(3)
    metrics.frame_received()
    metrics.frame_received()
    metrics.dropped("oversize")
    metrics.set_drops({"auth": 4, "replay": 1})
    metrics.set_drops({"auth": 5, "replay": 1})  # cumulative from the core: replaces
    metrics.dropped("auth")  # the runtime's own drops add to the core's
    metrics.observe_actions([
        Broadcast(b"x"), ev.Suspect(subject=2, function="f2"),
        ev.Vote(subject=2, function="f2", from_=1, count=1),
        ev.Vote(subject=2, function="f2", from_=3, count=2), Assign("f2", 1),
        ev.Takeover(function="f2", epoch=1, replaced=2),
    ])
    metrics.heartbeat_lateness(0.003)
    metrics.heartbeat_lateness(0.7)
    metrics.update(Snapshot(
        robot_id=5, role=Role.ACTIVE, function="f2", epoch=1, health=Health.OK,
        known={}, suspects={}, votes={"f1": 1}, drops={"auth": 5, "replay": 2}, seq=9,
    ))

    response = httpx.get(server.url, timeout=5)
    assert response.status_code == 200
    assert response.headers["content-type"].startswith("text/plain")
    s = _samples(response.text)
    assert s[("swarmd_frames_sent_total", ())] == 3
    assert s[("swarmd_frames_received_total", ())] == 2
    assert s[("swarmd_frames_dropped_total", (("reason", "auth"),))] == 6
    assert s[("swarmd_frames_dropped_total", (("reason", "replay"),))] == 2
    assert s[("swarmd_frames_dropped_total", (("reason", "oversize"),))] == 1
    assert s[("swarmd_events_total", (("event", "suspect"),))] == 1
    assert s[("swarmd_events_total", (("event", "vote"),))] == 2
    assert s[("swarmd_events_total", (("event", "takeover"),))] == 1
    assert s[("swarmd_events_total", (("event", "alert"),))] == 0  # present before use
    assert s[("swarmd_role", (("swarmd_role", "ACTIVE"),))] == 1
    assert s[("swarmd_role", (("swarmd_role", "STANDBY"),))] == 0
    assert s[("swarmd_function_info", (("function", "f2"),))] == 1
    assert s[("swarmd_epoch", ())] == 1
    assert s[("swarmd_votes", (("function", "f1"),))] == 1
    assert s[("swarmd_robot_info", (("robot", "5"), ("swarm", "1543")))] == 1
    assert s[("swarmd_heartbeat_lateness_seconds_count", ())] == 2
    assert s[("swarmd_heartbeat_lateness_seconds_bucket", (("le", "0.005"),))] == 1
    assert s[("swarmd_heartbeat_lateness_seconds_bucket", (("le", "1.0"),))] == 2

    # Later changes show on the next scrape: role and votes follow the node.
    metrics.set_role("STANDBY", None)
    metrics.set_votes({})
    s = _samples(httpx.get(server.url, timeout=5).text)
    assert s[("swarmd_role", (("swarmd_role", "STANDBY"),))] == 1
    assert s[("swarmd_function_info", (("function", ""),))] == 1
    assert s[("swarmd_votes", (("function", "f1"),))] == 0


def test_two_daemons_in_one_process_do_not_share_counters() -> None:
    a, b = Metrics(), Metrics()
    a.frame_sent()
    assert b"swarmd_frames_sent_total 0.0" in b.render()
    assert b"swarmd_frames_sent_total 1.0" in a.render()


def test_duplicate_id_frames_are_exported() -> None:
    m = Metrics()
    assert b"swarmd_duplicate_id_frames_total 0.0" in m.render()
    m.duplicate_id(3)
    assert b"swarmd_duplicate_id_frames_total 3.0" in m.render()


@pytest.mark.parametrize("host", ["0.0.0.0", "192.0.2.1", "::"])
def test_non_loopback_endpoint_is_refused(host: str) -> None:
    with pytest.raises(MetricsError, match="not a loopback address"):
        Metrics().start_server(host, 0)


def test_loopback_names_pass() -> None:
    for host in ("127.0.0.1", "localhost", "127.0.0.2"):
        check_loopback(host)


def test_busy_port_is_a_clear_error(served: tuple[Metrics, MetricsServer]) -> None:
    _, server = served
    with pytest.raises(MetricsError, match=f"cannot listen on 127.0.0.1:{server.port}"):
        Metrics().start_server("127.0.0.1", server.port)
