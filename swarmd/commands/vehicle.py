"""`swarmd sim vehicle`: one simulated PX4 or ArduPilot vehicle on loopback UDP
(sim/physics/vehicle.py; docs/mavlink.md). A subcommand of `swarmd sim` (commands/sim.py)."""

from __future__ import annotations

from typing import Annotated

import typer


def register(sim_app: typer.Typer) -> None:
    """Add `vehicle` to the `sim` command group."""

    @sim_app.command("vehicle")
    def vehicle(
        autopilot: Annotated[str, typer.Option(
            "--autopilot", metavar="NAME", help="Firmware the simulated autopilot answers "
            "as: px4 or ardupilot. Default: px4.")] = "px4",
        port: Annotated[int, typer.Option(
            "--port", metavar="PORT", min=0, max=65535, help="UDP port on 127.0.0.1 the "
            "vehicle listens on; clients send to it first (MAVSDK "
            "udpout://127.0.0.1:PORT). 0: a free port the kernel picks, printed in the "
            "connect line. Default: 14580 (PX4 SITL's).")] = 14580,
        sysid: Annotated[int, typer.Option(
            "--sysid", metavar="N", min=1, max=250,
            help="MAVLink system id of the vehicle. Default: 1.")] = 1,
        gcs_port: Annotated[int, typer.Option(
            "--gcs-port", metavar="PORT", min=0, max=65535, help="Also send telemetry from "
            "the start to this UDP port on 127.0.0.1, where a ground station listens "
            "(QGroundControl: 14550); 0: only to peers heard from. Default: 14550.")]
        = 14550,
        no_physics: Annotated[bool, typer.Option(
            "--no-physics", metavar="", help="Fly a point mass instead of the MuJoCo "
            "quadrotor: same MAVLink, far less CPU.")] = False,
    ) -> None:
        """Run one simulated vehicle (quadrotor and autopilot) until Ctrl-C or SIGTERM.

        A ground station, MAVSDK, pymavlink or a swarmd daemon connects to it over
        loopback UDP; the connection URLs are printed at start. It answers what PX4 or
        ArduPilot answer for the messages and commands in docs/mavlink.md: arming, modes,
        take-off, goto, return and landing, missions (upload, download, flown with
        progress), the parameters ground stations read, and message rates.

        Exit codes: 0 stopped by Ctrl-C or SIGTERM, 1 the port cannot be opened, 2 bad
        input or the simulation extra missing.

        Example: swarmd sim vehicle --autopilot ardupilot --port 14580 --no-physics
        """
        _vehicle(autopilot, port, sysid, gcs_port, no_physics)


def _vehicle(autopilot: str, port: int, sysid: int, gcs_port: int, no_physics: bool) -> None:
    """`swarmd sim vehicle`: check the input, then serve the vehicle; raises typer.Exit
    on failure."""
    import asyncio

    from sim.run import EXTRA_HINT, PHYSICS_MODULES, installed
    from swarmd.link.mavlink_modes import Flavour

    if autopilot not in ("px4", "ardupilot"):
        typer.echo(f"--autopilot: {autopilot!r} is not one of px4, ardupilot", err=True)
        raise typer.Exit(2)
    missing = [m for m in PHYSICS_MODULES if not installed(m)]
    if missing:  # the autopilot's craft models import them, also the point mass
        typer.echo(f"swarmd sim vehicle: needs the simulation extra ({', '.join(missing)} "
                   f"not installed): {EXTRA_HINT}", err=True)
        raise typer.Exit(2)
    from sim.physics.vehicle import run_vehicle
    flavour: Flavour = "px4" if autopilot == "px4" else "ardupilot"
    try:
        asyncio.run(run_vehicle(flavour, port, sysid, physics=not no_physics,
                                gcs_port=gcs_port,
                                say=lambda line: typer.echo(line)))
    except OSError as exc:
        typer.echo(f"--port: cannot listen on 127.0.0.1:{port}: {exc.strerror or exc}",
                   err=True)
        raise typer.Exit(1) from None
