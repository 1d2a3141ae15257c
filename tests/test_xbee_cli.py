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
