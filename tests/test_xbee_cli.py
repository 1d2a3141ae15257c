"""`swarmd xbee configure / info` against an emulated radio (real digi-xbee)."""

from __future__ import annotations

from pathlib import Path

import typer
from typer.testing import CliRunner

from sim.xbee_emu import Medium
from swarmd.commands import xbee as xbee_cmd


def _app() -> typer.Typer:
    app = typer.Typer()
    xbee_cmd.register(app)

    @app.command("noop")
    def noop() -> None:  # a second command keeps `xbee` a sub-command group
        """Nothing."""

    return app


def test_configure_applies_paper_settings_and_prints_before_after(tmp_path: Path) -> None:
    with Medium(2, protocol="802.15.4", directory=tmp_path) as medium:
        result = CliRunner().invoke(_app(), [
            "xbee", "configure", "--port", medium.path(1), "--role", "coordinator",
            "--pan", "0x607", "--channel", "0x0F", "--protocol", "802.15.4", "--write"])
        assert result.exit_code == 0, result.output
        assert "CH" in result.output and "0F  *" in result.output
        radio = medium.radios[1]
        assert radio.saved["CH"] == b"\x0f"  # written to flash
        assert radio.saved["DL"] == b"\x00\x00\xff\xff"  # coordinator broadcasts (paper)
        assert radio.saved["MY"] == b"\xff\xfe"
        info = CliRunner().invoke(_app(), ["xbee", "info", "--port", medium.path(1)])
        assert info.exit_code == 0, info.output
        assert "802.15.4" in info.output and "0013A20040000001" in info.output


def test_configure_refuses_wrong_firmware_and_missing_port(tmp_path: Path) -> None:
    with Medium(1, protocol="digimesh", directory=tmp_path) as medium:
        result = CliRunner().invoke(_app(), [
            "xbee", "configure", "--port", medium.path(1), "--role", "router",
            "--protocol", "zigbee"])
        assert result.exit_code == 1
        assert "runs digimesh firmware, not zigbee" in result.output
    missing = CliRunner().invoke(_app(), ["xbee", "info", "--port", str(tmp_path / "none")])
    assert missing.exit_code == 1 and "cannot open" in missing.output


def test_configure_channel_per_firmware(tmp_path: Path) -> None:
    # Zigbee's CH is read-only: --channel becomes the scan mask SC, and the network
    # moves to that channel; elsewhere it is CH. Out of 0x0B-0x1A: a usage error.
    for firmware, name in (("zigbee", "SC"), ("digimesh", "CH")):
        with Medium(1, protocol=firmware, directory=tmp_path / firmware) as medium:
            result = CliRunner().invoke(_app(), [
                "xbee", "configure", "--port", medium.path(1), "--role", "router",
                "--channel", "0x0F"])
            assert result.exit_code == 0, result.output
            radio = medium.radios[1]
            assert radio.params["CH"] == b"\x0f"
            if name == "SC":
                assert radio.params["SC"] == b"\x00\x10"
            bad = CliRunner().invoke(_app(), [
                "xbee", "configure", "--port", medium.path(1), "--role", "router",
                "--channel", "0x05"])
            assert bad.exit_code == 2 and "0x0B..0x1A" in bad.output


def test_configure_names_the_setting_the_radio_refused(tmp_path: Path) -> None:
    with Medium(1, protocol="802.15.4", directory=tmp_path) as medium:
        radio = medium.radios[1]
        radio._valid = lambda cmd, value: cmd != "ID"  # type: ignore[method-assign]
        result = CliRunner().invoke(_app(), [
            "xbee", "configure", "--port", medium.path(1), "--role", "router",
            "--pan", "0x1234", "--write"])
        assert result.exit_code == 1
        lines = [line for line in result.output.splitlines() if "refused" in line]
        assert lines == ["the radio refused ID=0x1234: Invalid parameter; nothing was saved"]
        assert radio.saved["ID"] == b"\x06\x07"
