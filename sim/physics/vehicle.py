"""`swarmd sim vehicle`: one simulated vehicle (a quadrotor and its PX4 or ArduPilot
autopilot, sim/physics/autopilot.py) on a loopback UDP port, for a ground station, an SDK
or a daemon to connect to, until Ctrl-C or SIGTERM (docs/mavlink.md).

The craft is the MuJoCo quadrotor, or with `physics=False` a point mass
(sim/physics/point.py) that needs a few microseconds of CPU a step.
"""

from __future__ import annotations

import asyncio
import signal
from collections.abc import Callable

from swarmd.link.mavlink_modes import Flavour

HOST = "127.0.0.1"


def _stop_on_signals(loop: asyncio.AbstractEventLoop,
                     stop: asyncio.Event) -> list[signal.Signals]:
    """SIGINT and SIGTERM set `stop` where the loop can handle them: the ones handled."""
    handled: list[signal.Signals] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            loop.add_signal_handler(sig, stop.set)
            handled.append(sig)
        except (NotImplementedError, RuntimeError):  # not the main thread: `stop` only
            pass
    return handled


async def run_vehicle(flavour: Flavour, port: int, sysid: int, *, physics: bool = True,
                      gcs_port: int = 0, say: Callable[[str], None] = print,
                      stop: asyncio.Event | None = None) -> None:
    """Serve one vehicle on UDP `HOST:port` until `stop` is set or SIGINT / SIGTERM.
    Telemetry goes to every peer heard from, and to `gcs_port` (if not 0) from the
    start, as PX4 SITL sends to a ground station's 14550. Raises OSError if the port
    cannot be opened. Port 0: the one the kernel gives it when it binds, which the
    connect line names."""
    from sim.physics.autopilot import start_autopilot
    from sim.physics.link import QuadLink
    from sim.physics.point import PointLink

    craft: QuadLink | PointLink = QuadLink(sysid, (0.0, 0.0, 0.0)) if physics else (
        PointLink(sysid, (0.0, 0.0, 0.0)))
    peers = [(HOST, gcs_port)] if gcs_port else []
    stop = stop or asyncio.Event()
    loop = asyncio.get_running_loop()
    handled = _stop_on_signals(loop, stop)
    try:
        ap = await start_autopilot(craft, flavour, port, sysid=sysid, host=HOST, peers=peers)
    except OSError:
        await craft.close()
        raise
    # The port it listens on: `port`, or the kernel's pick for port 0. A client started
    # after it reads this one from the connect line, so that nobody has to probe a free
    # port and hope that no other process takes it before the vehicle binds it.
    port = ap.port
    try:
        lat, lon, alt = ap.core.home_geo()
        say(f"vehicle: {flavour} autopilot, MAVLink system {sysid}, "
            f"{'MuJoCo quadrotor' if physics else 'point mass (no physics)'}, home "
            f"{lat:.6f}, {lon:.6f}, {alt:.1f} m")
        say(f"connect: MAVSDK udpout://{HOST}:{port} | pymavlink / MAVProxy "
            f"udpout:{HOST}:{port} | QGroundControl: UDP link to server {HOST}:{port}"
            + (f" (telemetry also sent to {HOST}:{gcs_port})" if gcs_port else ""))
        say("Ctrl-C or SIGTERM stops it")
        await stop.wait()
    finally:
        for sig in handled:
            loop.remove_signal_handler(sig)
        await ap.close()
        await craft.close()
        say("vehicle: stopped")
