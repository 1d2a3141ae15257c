"""`swarmd sim SWARM.yaml`: the whole swarm on this machine (DESIGN section 3).

Without `--virtual`: one OS process per robot, each a real daemon over UDP multicast on
loopback (`sim.realtime`). With `--virtual`: every robot's protocol core in this process
on a virtual clock (`sim.virtual`), deterministic by `--seed`, far faster than real
time. Both write the same event log and print the same summary.

This module only parses the command line, builds `sim.run.SimOptions`, calls
`sim.run.run_sim` and prints its result; what is checked, run and written is there.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from typer.core import TyperArgument, TyperGroup

from swarmd.commands.numbers import finite, probability

if TYPE_CHECKING:
    from sim.run import SimError, SimOptions

FAULT_HELP = (
    "Inject a fault (repeatable), e.g. crash:2@5: robot 2 dies 5 s into the run. Every "
    "kind is listed below the options; docs/sim.md tells more."
)


def _fault_kinds() -> str:
    """The fault table under the options (sim/shared/faults.py, the one source)."""
    from rich.markup import escape

    from sim.shared.faults import help_table

    return escape(help_table())


# Typer may vend its own copy of click: take its Command class from the group's bases.
_COMMAND: Any = next(c for c in TyperGroup.__mro__ if c.__name__ == "Command")


class _SimGroup(TyperGroup):
    """`swarmd sim SWARM [options]` runs a swarm, as a plain command would; a first word
    naming a subcommand (`swarmd sim vehicle ...`) runs that instead. A group whose own
    parameters are the run's, so both forms parse and `--help` lists both."""

    _SUB = "swarmd.sim.subcommand"

    # The fault table under the options, built when help is shown rather than when the
    # CLI is assembled: it imports the simulator's package, which a robot's daemon
    # (`swarmd start`, the same CLI) never needs, and 1.5 MB of its memory with it.
    @property
    def epilog(self) -> str:
        return _fault_kinds()

    @epilog.setter
    def epilog(self, value: str | None) -> None:
        """Click's constructor sets it; the table above is the epilog."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.allow_interspersed_args = True  # options after SWARM, as before
        self.allow_extra_args = False
        self.no_args_is_help = False

    def parse_args(self, ctx: Any, args: list[str]) -> list[str]:
        if args and args[0] in self.commands:
            ctx.meta[self._SUB] = (args[0], list(args[1:]))
            return []
        return super().parse_args(ctx, args)

    def get_params(self, ctx: Any) -> Any:
        params = super().get_params(ctx)
        if self._SUB in ctx.meta:  # `swarmd sim vehicle`, not `swarmd sim SWARM vehicle`
            return [p for p in params if not isinstance(p, TyperArgument)]
        return params

    def collect_usage_pieces(self, ctx: Any) -> Any:
        return _COMMAND.collect_usage_pieces(self, ctx)

    def invoke(self, ctx: Any) -> Any:
        if self._SUB not in ctx.meta:
            return _COMMAND.invoke(self, ctx)
        name, args = ctx.meta[self._SUB]
        ctx.invoked_subcommand = name
        with ctx:
            sub = self.commands[name].make_context(name, args, parent=ctx)
            with sub:
                return sub.command.invoke(sub)


# Each option's declaration (flag, range, help) as a type of its own, so the signature
# of `sim` stays short beside its docstring (the --help text).
SwarmArg = Annotated[Path, typer.Argument(help="Swarm file, e.g. configs/paper.yaml.")]
VirtualOpt = Annotated[bool, typer.Option(
    "--virtual", metavar="", help="Run every protocol core in this process on a virtual "
    "clock: deterministic by --seed, far faster than real time, no robot "
    "processes, no physics.")]
DurationOpt = Annotated[float, typer.Option(
    "--duration", metavar="S", min=0.1, callback=finite,
    help="Length of the run in seconds "
    "(wall-clock in real time, simulated with --virtual).")]
SeedOpt = Annotated[int, typer.Option("--seed", metavar="N", min=0, help="Seed of frame loss, "
                                      "jitter and start times, 0 or more.")]
LossOpt = Annotated[float, typer.Option(
    "--loss", metavar="P", callback=probability, help="Probability, 0 to below 1, "
    "that a receiver misses a frame (drawn per frame and per receiver).")]
LossModelOpt = Annotated[str, typer.Option(
    "--loss-model", metavar="M", help="How --loss falls: bernoulli (each frame on "
    "its own) or burst (Gilbert-Elliott per link: runs of lost frames, as a radio "
    "fades; the same mean loss).")]
BurstLenOpt = Annotated[float, typer.Option(
    "--burst-len", metavar="L", min=1.0, callback=finite, help="--loss-model "
    "burst: mean length of a loss burst, in frames.")]
FaultOpt = Annotated[list[str] | None, typer.Option("--fault", metavar="SPEC", help=FAULT_HELP)]
EventsOpt = Annotated[Path | None, typer.Option(
    "--events", metavar="FILE",
    help="Also write the merged event log to this file (JSON Lines, "
    "one event a line). Default: not written.")]
ReportOpt = Annotated[Path | None, typer.Option(
    "--report", metavar="DIR",
    help="Directory for summary.json, events.jsonl, timeline.png and, "
    "with physics, trajectories.png, swarm.mp4 and key frames; what an earlier run "
    "wrote there is removed first. Default: no report.")]
JsonOpt = Annotated[bool, typer.Option(
    "--json", metavar="", help="Print the summary as JSON on stdout; no live table, the "
    "report lines go to stderr.")]
NoPhysicsOpt = Annotated[bool, typer.Option(
    "--no-physics", metavar="", help="Real time with bare daemons (robot link 'none'): no "
    "MuJoCo quadrotors, so no trajectories or video.")]
CraftOpt = Annotated[str | None, typer.Option(
    "--craft", metavar="NAME",
    help="Quadrotor every robot flies (physics only): x2 (Skydio "
    "X2-class, 1.3 kg, visible in pictures) or crazyflie (27 g). Default: "
    "$SWARMD_QUAD_PRESET, else x2.")]
TransportOpt = Annotated[str, typer.Option(
    "--transport", metavar="NAME",
    help="Channel in real time: udp (multicast on loopback), xbee "
    "or serial (emulated radios on pseudo-terminals). Refused with --virtual.")]
LinkOpt = Annotated[str, typer.Option(
    "--link", metavar="NAME",
    help="How each daemon reaches its quadrotor (physics only): direct "
    "(the daemon's link drives the MuJoCo craft) or mavlink (the daemon's MAVLink "
    "link over loopback UDP to a simulated autopilot, one system id and UDP port per "
    "robot, that flies the craft; faults reach the daemon only as MAVLink health) "
    "or ros2 (the daemon's ROS 2 link and a small rclpy robot stack per robot, in "
    "domain $ROS_DOMAIN_ID when it is set, else one leased for the run; the first "
    "line names it and how to watch it; also with --no-physics; needs "
    "swarmd\\[ros2], docs/ros2.md). Default: direct.")]
AutopilotOpt = Annotated[str | None, typer.Option(
    "--autopilot", metavar="NAME",
    help="Flavour of the simulated autopilot of --link mavlink: px4 "
    "(OFFBOARD setpoints) or ardupilot (GUIDED). Default: px4.")]
RefuseArmOpt = Annotated[list[int] | None, typer.Option(
    "--refuse-arm", metavar="R", min=1, max=0xFFFF,
    help="Robot id whose simulated autopilot "
    "denies every arm command, as a failing pre-arm check (repeatable; --link "
    "mavlink only). Default: none.")]


def register(app: typer.Typer) -> None:
    """Add the `sim` command (and its `vehicle` subcommand) to the CLI."""
    sim_app = typer.Typer(cls=_SimGroup, invoke_without_command=True)
    app.add_typer(sim_app, name="sim")
    from swarmd.commands import vehicle

    vehicle.register(sim_app)
    sim_app.callback()(sim)


def sim(
    swarm: SwarmArg, virtual: VirtualOpt = False, duration: DurationOpt = 15.0,
    seed: SeedOpt = 0, loss: LossOpt = 0.0, loss_model: LossModelOpt = "bernoulli",
    burst_len: BurstLenOpt = 4.0, fault: FaultOpt = None, events: EventsOpt = None,
    report: ReportOpt = None, json_out: JsonOpt = False, no_physics: NoPhysicsOpt = False,
    craft: CraftOpt = None, transport: TransportOpt = "udp", link: LinkOpt = "direct",
    autopilot: AutopilotOpt = None, refuse_arm: RefuseArmOpt = None,
) -> None:
    """Run the whole swarm on this machine, inject faults, print a summary.

    Default: one process per robot, each a real daemon (the code swarmd start runs)
    flying a MuJoCo quadrotor, over UDP multicast on loopback. --link mavlink: each
    daemon flies its quadrotor through a simulated PX4 or ArduPilot autopilot over
    MAVLink. --no-physics: the same without quadrotors. --virtual: one process on a
    virtual clock. `swarmd sim vehicle` runs one simulated vehicle instead (its own
    --help).

    Exit codes: 0 no invariant violated, 1 an invariant was violated or a robot
    process failed, 2 bad input (swarm file, --fault, --craft, --link, --report; nothing was
    started), 130 / 143 ended early by Ctrl-C / SIGTERM (partial report).

    Example: swarmd sim configs/paper.yaml --fault crash:2@5 --duration 15 --report out/demo

    Example: swarmd sim configs/paper.yaml --link mavlink --fault motor:2@5
    """
    from sim.run import SimError, SimOptions

    try:
        options = SimOptions(
            swarm=swarm, virtual=virtual, duration=duration, seed=seed, loss=loss,
            loss_model=loss_model, burst_len=burst_len,
            faults=tuple(fault or ()), events=events, report=report,
            physics=not no_physics, craft=craft, transport=transport,
            live=not json_out, link=link, autopilot=autopilot,
            refuse_arm=tuple(refuse_arm or ()))
    except SimError as exc:
        raise _refused(exc) from None
    _run(options, json_out=json_out)


def _refused(exc: SimError) -> typer.Exit:
    """Print why the run was refused, one problem a line; the exit (2) to raise."""
    from rich.console import Console

    # Problems are plain text: no rich markup (a `[x, y, z]` in a message is not a
    # tag) and no wrapping (one problem a line, for grep).
    err = Console(stderr=True, highlight=False, markup=False, soft_wrap=True)
    for line in exc.lines:
        err.print(line)
    return typer.Exit(2)


def _run(options: SimOptions, *, json_out: bool) -> None:
    """Run the swarm, print its summary (JSON on stdout with `json_out`, else a table)
    and what --report wrote, and exit with the run's code."""
    from rich.console import Console

    from sim.run import SimError, run_sim

    try:
        result = run_sim(options)
    except SimError as exc:
        raise _refused(exc) from None
    out = Console(highlight=False, stderr=json_out)
    if json_out:
        typer.echo(result.summary.to_json())
    else:
        from sim.shared.summary import render_summary

        render_summary(result.summary, out)
    if options.report is not None:
        _say_report(out, options.report, result.pictures, physics=options.flies)
    if result.interrupted:  # Ctrl-C / SIGTERM: the shell's 128 + signal number
        import signal

        raise typer.Exit(128 + signal.Signals[result.interrupted].value)
    raise typer.Exit(0 if result.summary.ok else 1)


def _say_report(out: Any, report: Path, pictures: dict[str, Any], *, physics: bool) -> None:
    """Tell the user what `--report` wrote and, when a picture is missing, why: a
    missing GL backend must not look like a silent success."""
    names = sorted(p.name for p in report.iterdir() if p.is_file())
    out.print(f"report: {report}/ — {', '.join(names)}", soft_wrap=True)
    if not physics:
        out.print("report: trajectories and video need physics (not with --virtual or "
                  "--no-physics)")
    for problem in pictures.get("skipped", []):
        out.print(f"report: trajectory file skipped: {problem}")
    if pictures.get("video_error"):
        out.print(f"report: no video or key frames: {pictures['video_error']} "
                  "(scripts/system-deps.sh installs a headless GL backend)")
