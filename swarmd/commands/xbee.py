"""`swarmd xbee ...`: configure a radio the paper's way, show what it is, emulate radios.

- `configure --port P --role coordinator|router --pan 0x607 [--channel C] [--write]`
  applies the paper's settings (docs/radios.md): PAN id, coordinator CE=1 with DH/DL
  0x0000/0xFFFF (broadcast), routers CE=0 (SM=0 on Zigbee) with DH/DL 0x0000/0x0000,
  and on 802.15.4 MY=0xFFFE (64-bit source addresses: the digi-xbee 0x81 stall). It
  prints every setting before and after; `--write` saves to flash (WR).
- `info --port P` prints protocol, firmware, address and the settings above.
- `emulate N` runs N software radios on ptys until Ctrl-C (sim.xbee_emu); lines on
  stdin such as `unplug 2`, `replug 2`, `loss 2 0.3`, `delay 2 0.05` change them live.
"""

from __future__ import annotations

from typing import Annotated, Any

import typer

from swarmd.commands.numbers import finite, probability
from swarmd.transport.media import PROTOCOL_NAMES, PROTOCOLS

SETTINGS = ("AP", "ID", "CH", "SC", "CE", "SM", "MY", "DH", "DL", "NI", "EE")
CHANNELS = range(0x0B, 0x1B)
"""2.4 GHz channels 11-26; bit i of Zigbee's SC mask is channel 11 + i."""


def _int(text: str) -> int:
    """Accept 0x607 (hex, as the paper types PAN ids) or decimal 1543."""
    try:
        return int(text, 0)
    except ValueError:
        raise typer.BadParameter(f"not a number: {text!r} (write 0x607 or 1543)") from None


def _read(dev: Any) -> dict[str, str]:
    """Current values of SETTINGS as hex strings ('-' where the firmware has none)."""
    from digi.xbee.exception import XBeeException

    out: dict[str, str] = {}
    for name in SETTINGS:
        try:
            value = bytes(dev.get_parameter(name))
        except XBeeException:
            out[name] = "-"
            continue
        out[name] = value.decode(errors="replace") if name == "NI" else (
            value.hex().upper() or "0")
    return out


def paper_settings(protocol: str, role: str, pan: int, channel: int | None,
                   api_mode: int | None) -> dict[str, bytes]:
    """The AT settings `configure` applies (see the module docstring)."""
    wanted: dict[str, bytes] = {"ID": pan.to_bytes(2, "big")}
    if role == "coordinator":
        wanted.update(CE=b"\x01", DH=b"\x00\x00\x00\x00", DL=b"\x00\x00\xff\xff")
    else:
        wanted.update(CE=b"\x00", DH=b"\x00\x00\x00\x00", DL=b"\x00\x00\x00\x00")
        if protocol == "zigbee":
            wanted["SM"] = b"\x00"
    if protocol == "802.15.4":
        wanted["MY"] = b"\xff\xfe"
    if channel is not None:
        if protocol == "zigbee":
            # Zigbee's CH is read-only (the channel the network formed on): the
            # coordinator forms, and routers join, within the SC mask.
            wanted["SC"] = (1 << (channel - CHANNELS.start)).to_bytes(2, "big")
        else:
            wanted["CH"] = bytes((channel,))
    if api_mode is not None:
        wanted["AP"] = bytes((api_mode,))
    return wanted


def _open(port: str, baud: int) -> Any:
    from digi.xbee.devices import XBeeDevice
    from digi.xbee.exception import XBeeException
    from serial import SerialException

    dev = XBeeDevice(port, baud)
    try:
        dev.open()
    except (XBeeException, SerialException, OSError) as exc:
        typer.echo(f"cannot open an XBee in API mode on {port} at {baud} baud: {exc}\n"
                   "digi-xbee needs API mode (AP=1 or 2); check the port, the baud rate "
                   "(BD) and that no other program holds the port.", err=True)
        raise typer.Exit(1) from None
    return dev


def _protocol(dev: Any) -> str:
    name = str(dev.get_protocol().name)
    return PROTOCOL_NAMES.get(name, name.lower())


# The options `info` and `configure` share, declared once.
PortOpt = Annotated[str, typer.Option(help="Serial device of the radio, e.g. /dev/xbee.")]
BaudOpt = Annotated[int, typer.Option(min=1, help="UART baud rate, bit/s (the radio's BD).")]


def register(app: typer.Typer) -> None:
    """Add the `xbee` command group to the CLI."""
    xbee = typer.Typer(
        help="Configure, inspect or emulate XBee radios (docs/radios.md).\n\n"
        "The daemon drives XBees in API mode through digi-xbee; stop it before "
        "configuring its radio (the port is opened exclusively).\n\n"
        "Example: swarmd xbee info --port /dev/xbee",
        no_args_is_help=True)
    app.add_typer(xbee, name="xbee")
    xbee.command("info")(info)
    xbee.command("configure")(configure)
    xbee.command("emulate")(emulate)


def info(port: PortOpt, baud: BaudOpt = 9600) -> None:
    """Print what the radio is: protocol, firmware, address, network settings.

    Exit codes: 0 printed, 1 no XBee in API mode answers on --port at --baud.

    Example: swarmd xbee info --port /dev/xbee
    """
    dev = _open(port, baud)
    try:
        typer.echo(f"port       {port}")
        typer.echo(f"protocol   {_protocol(dev)}")
        typer.echo(f"hardware   {dev.get_hardware_version().description}")
        typer.echo(f"firmware   {bytes(dev.get_firmware_version()).hex().upper()}")
        typer.echo(f"address    {dev.get_64bit_addr()}")
        typer.echo(f"role       {dev.get_role().description}")
        typer.echo(f"api mode   {dev.operating_mode.description}")
        for name, value in _read(dev).items():
            typer.echo(f"{name:<10} {value}")
    finally:
        dev.close()


def configure(
    port: PortOpt,
    role: Annotated[str, typer.Option(help="coordinator or router (paper: one "
                                      "coordinator, the rest routers).")],
    pan: Annotated[str, typer.Option(help="PAN id (ID), hex 0x607 or decimal; the "
                                     "same on every robot.")] = "0x607",
    channel: Annotated[str | None, typer.Option(
        help="Channel, 0x0B-0x1A (11-26), e.g. 0x0C: CH on 802.15.4 and DigiMesh; "
             "on Zigbee the scan mask SC holding only that channel (CH is "
             "read-only there). Default: keep the radio's.")] = None,
    protocol: Annotated[str | None, typer.Option(
        help="Expected firmware: zigbee, 802.15.4 or digimesh (checked, not "
             "changed: that needs a firmware update in XCTU). Default: not "
             "checked.")] = None,
    api_mode: Annotated[int | None, typer.Option(
        min=1, max=2, help="Set AP to 1 or 2. Default: keep the radio's.")] = None,
    baud: BaudOpt = 9600,
    write: Annotated[bool, typer.Option("--write", help="Save to flash (WR) so the "
                                        "settings survive a power cycle. Default: "
                                        "applied only.")] = False,
) -> None:
    """Apply the paper's radio settings and print them before and after.

    PAN id; coordinator CE=1, DH/DL 0x0000/0xFFFF; routers CE=0 (SM=0 on Zigbee),
    DH/DL 0x0000/0x0000; MY=0xFFFE on 802.15.4. Changed settings are starred.

    Exit codes: 0 applied, 1 the radio cannot be opened, runs other firmware than
    --protocol or refused a setting, 2 a bad option value.

    Example: swarmd xbee configure --port /dev/xbee --role router --pan 0x607 --write
    """
    _configure(port, role=role, pan=pan, channel=channel, protocol=protocol,
               api_mode=api_mode, baud=baud, write=write)


def emulate(
    count: Annotated[int, typer.Argument(min=1, help="Number of radios (robot1..robotN).")],
    protocol: Annotated[str, typer.Option(help="Firmware emulated: zigbee, 802.15.4 "
                                          "or digimesh.")] = "802.15.4",
    api_mode: Annotated[int, typer.Option(min=1, max=2, help="API mode (AP), 1 or 2.")] = 1,
    loss: Annotated[float, typer.Option(
        callback=probability, help="Probability, 0 to below 1, that a "
        "frame sent or received by a radio is lost.")] = 0.0,
    delay: Annotated[float, typer.Option(
        min=0.0, callback=finite,
        help="Extra delivery delay of every radio's frames, seconds.")] = 0.0,
    pan: Annotated[str, typer.Option(help="PAN id of every radio.")] = "0x607",
    channel: Annotated[str, typer.Option(help="Channel of every radio.")] = "0x0C",
    directory: Annotated[str, typer.Option("--dir", help="Directory of the device "
                                           "symlinks robot1..robotN.")] = "/tmp/swarmd-xbee",
    seed: Annotated[int | None, typer.Option(
        min=0, help="Seed of the loss draws, 0 or more. Default: random.")] = None,
    transparent: Annotated[bool, typer.Option(
        "--transparent", help="AP=0 radios (raw byte stream, for transport kind "
        "serial) instead of API mode.")] = False,
) -> None:
    """Run N software XBee radios on pseudo-terminals until Ctrl-C.

    Radios with one protocol, PAN id and channel hear each other; point a robot
    file's port at DIR/robotN. Lines on stdin change them live: unplug N, replug N,
    loss N P, delay N S.

    Exit codes: 0 stopped with Ctrl-C, 2 a bad option value.

    Example: swarmd xbee emulate 6 --protocol 802.15.4 --loss 0.05
    """
    _emulate(count, protocol=protocol, api_mode=api_mode, directory=directory,
             pan=pan, channel=channel, loss=loss, delay=delay, seed=seed,
             transparent=transparent)


def _emulate(count: int, *, protocol: str, api_mode: int, directory: str, pan: str,
             channel: str, loss: float, delay: float, seed: int | None,
             transparent: bool) -> None:
    """`swarmd xbee emulate`: check the options, run the radios until Ctrl-C."""
    import sys

    from sim.xbee_emu import Medium

    if protocol not in PROTOCOLS:
        raise typer.BadParameter(f"--protocol must be one of {', '.join(PROTOCOLS)}")
    if api_mode not in (1, 2):
        raise typer.BadParameter("--api-mode must be 1 or 2")
    if not 0 <= loss <= 1:
        raise typer.BadParameter("--loss must be between 0 and 1")
    medium = Medium(count, protocol=protocol, api_mode=api_mode, directory=directory,
                    pan_id=_int(pan), channel=_int(channel), loss=loss, delay=delay,
                    seed=seed, transparent=transparent)
    medium.start()
    try:
        mode = "transparent (AP=0)" if transparent else f"API mode {api_mode}"
        typer.echo(f"{count} emulated {protocol} radios, {mode}, PAN "
                   f"0x{_int(pan):04X}, channel 0x{_int(channel):02X}:")
        for n in medium.radios:
            typer.echo(f"  robot{n}: {medium.path(n)}")
        typer.echo("commands on stdin: unplug N | replug N | loss N P | delay N S; "
                   "Ctrl-C stops")
        _command_loop(medium, sys.stdin)
    except KeyboardInterrupt:
        pass
    finally:
        medium.stop()


def _configure(port: str, *, role: str, pan: str, channel: str | None, protocol: str | None,
               api_mode: int | None, baud: int, write: bool) -> None:
    """`swarmd xbee configure`: check the options, apply, print the settings."""
    if role not in ("coordinator", "router"):
        raise typer.BadParameter("--role must be coordinator or router")
    if api_mode not in (None, 1, 2):
        raise typer.BadParameter("--api-mode must be 1 or 2 (digi-xbee needs API mode)")
    pan_id = _int(pan)
    ch = _int(channel) if channel is not None else None
    if ch is not None and ch not in CHANNELS:
        raise typer.BadParameter(f"--channel must be 0x0B..0x1A (11-26), got 0x{ch:02X}")
    before, after = _reconfigure(port, baud, protocol, write,
                                 role=role, pan_id=pan_id, channel=ch, api_mode=api_mode)
    typer.echo(f"{'':<4} {'before':>18} {'after':>18}")
    for name in SETTINGS:
        mark = "  *" if before[name] != after[name] else ""
        typer.echo(f"{name:<4} {before[name]:>18} {after[name]:>18}{mark}")
    typer.echo("saved to flash (WR)" if write else
               "applied but not saved: add --write to keep it across a power cycle")


def _reconfigure(port: str, baud: int, protocol: str | None, write: bool, *, role: str,
                 pan_id: int, channel: int | None,
                 api_mode: int | None) -> tuple[dict[str, str], dict[str, str]]:
    """Open the radio, check its firmware, apply the paper's settings (and save them
    with `write`): the settings read before and after."""
    dev = _open(port, baud)
    try:
        actual = _protocol(dev)
        if protocol is not None and protocol != actual:
            typer.echo(f"the radio on {port} runs {actual} firmware, not {protocol}; "
                       "load the firmware with XCTU first", err=True)
            raise typer.Exit(1)
        before = _read(dev)
        _apply(dev, paper_settings(actual, role, pan_id, channel, api_mode), write)
        after = _read(dev)
    finally:
        dev.close()
    return before, after


def _apply(dev: Any, wanted: dict[str, bytes], write: bool) -> None:
    """Queue every setting, apply them together, save them with `write`; a refusal
    is reported and exits 1."""
    from digi.xbee.exception import XBeeException

    name, value = "AC", b""
    try:
        for name, value in wanted.items():
            dev.set_parameter(name, value, apply=False)  # queued (0x09) ...
        name, value = "AC", b""
        dev.apply_changes()  # ... and applied together (AC)
        if write:
            name = "WR"
            dev.write_changes()  # WR
    except XBeeException as exc:
        status = getattr(exc, "status", None)
        why = status.description if status is not None else str(exc)
        typer.echo(f"the radio refused {name}"
                   f"{'=0x' + value.hex().upper() if value else ''}: {why}; "
                   "nothing was saved", err=True)
        raise typer.Exit(1) from None


def _command_loop(medium: Any, stream: Any) -> None:
    import time

    for line in stream:
        words = line.split()
        try:
            match words:
                case ["unplug", n]:
                    medium.unplug(int(n))
                case ["replug", n]:
                    medium.replug(int(n))
                case ["loss", n, p]:
                    medium.set_loss(int(n), float(p))
                case ["delay", n, s]:
                    medium.set_delay(int(n), float(s))
                case []:
                    continue
                case _:
                    typer.echo(f"unknown command: {line.strip()}", err=True)
                    continue
        except (KeyError, ValueError) as exc:
            typer.echo(f"bad command {line.strip()!r}: {exc}", err=True)
            continue
        typer.echo(f"ok: {line.strip()}")
    while True:  # stdin closed (e.g. run from a script): keep serving until Ctrl-C
        time.sleep(3600)
