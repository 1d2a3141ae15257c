"""deploy/: systemd units checked by systemd itself, install.sh into a temporary root.

Nothing here touches the host: units are verified from temporary copies, install.sh
runs with --root, systemd-sysusers with --root.
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from swarmd.base.identity import write_identity

REPO = Path(__file__).resolve().parent.parent
DEPLOY = REPO / "deploy"
UNITS = ("swarmd.service", "swarmd@.service")
SHIPPED_BIN = "/usr/local/bin/swarmd"


def _unit_entries(text: str) -> dict[str, list[str]]:
    """`Section.Key` -> values, in order (systemd allows repeated keys)."""
    out: dict[str, list[str]] = {}
    section = ""
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("["):
            section = line.strip("[]")
            continue
        key, _, value = line.partition("=")
        out.setdefault(f"{section}.{key}", []).append(value)
    return out


def _analyze() -> str:
    exe = shutil.which("systemd-analyze")
    if exe is None:
        pytest.skip("systemd-analyze not installed (apt-get install systemd; "
                    "scripts/system-deps.sh does it)")
    return exe


def _runnable_copy(unit: str, tmp_path: Path, name: str | None = None) -> Path:
    """The shipped unit with only ExecStart's binary pointed at an existing file
    (`verify` checks that the binary exists and is executable)."""
    exe = shutil.which("swarmd") or "/bin/true"
    text = (DEPLOY / unit).read_text()
    assert SHIPPED_BIN in text
    dst = tmp_path / (name or unit)
    dst.write_text(text.replace(SHIPPED_BIN, exe))
    return dst


def _verify(path: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [_analyze(), "verify", str(path)], capture_output=True, text=True, timeout=60,
        cwd=path.parent,
    )


@pytest.mark.parametrize(
    ("unit", "as_name"),
    [("swarmd.service", None), ("swarmd@.service", None),
     ("swarmd@.service", "swarmd@robot1.service")],
)
def test_units_pass_systemd_analyze_verify(tmp_path: Path, unit: str, as_name: str | None) -> None:
    path = _runnable_copy(unit, tmp_path, as_name)
    result = _verify(path)
    # systemd 252 exits 0 on "Unknown key" and parse warnings: any output is a finding.
    assert result.returncode == 0, result.stderr
    assert result.stdout + result.stderr == ""


def test_verify_reports_a_broken_unit(tmp_path: Path) -> None:
    # The check above is only worth something if systemd-analyze speaks up here.
    path = _runnable_copy("swarmd.service", tmp_path)
    path.write_text(path.read_text().replace("Type=notify", "Type=notfy"))
    result = _verify(path)
    assert "Failed to parse service type" in result.stdout + result.stderr


def test_units_security_exposure_is_low(tmp_path: Path) -> None:
    path = _runnable_copy("swarmd.service", tmp_path)
    result = subprocess.run(
        [_analyze(), "security", "--offline=yes", str(path)],
        capture_output=True, text=True, timeout=60, cwd=tmp_path,
    )
    match = re.search(r"Overall exposure level for \S+: (\d+\.\d+)", result.stdout + result.stderr)
    if match is None:
        pytest.skip(f"systemd-analyze security --offline unsupported here: {result.stderr}")
    # systemd's scale: 0 (locked down) .. 10 (unprotected); "OK" is below 2.
    assert float(match.group(1)) <= 2.0


@pytest.mark.parametrize("unit", UNITS)
def test_units_run_the_daemon_as_a_watched_confined_service(unit: str) -> None:
    e = _unit_entries((DEPLOY / unit).read_text())
    assert e["Service.Type"] == ["notify"]
    assert e["Service.NotifyAccess"] == ["main"]
    assert float(e["Service.WatchdogSec"][0]) > 0
    assert e["Service.Restart"] == ["on-failure"]
    assert e["Service.User"] == ["swarmd"]
    assert e["Service.SupplementaryGroups"] == ["dialout"]
    assert e["Service.ProtectSystem"] == ["strict"]
    assert e["Service.NoNewPrivileges"] == ["yes"]
    assert e["Service.StateDirectory"][0].startswith("swarmd")
    assert e["Service.ExecStart"][0].startswith(f"{SHIPPED_BIN} start --config /etc/swarmd/")
    if "@" in unit:
        assert "%i" in e["Service.ExecStart"][0]
        assert e["Service.StateDirectory"] == ["swarmd/%i"]


def test_udev_rule_names_the_xbee() -> None:
    rules = [
        line for line in (DEPLOY / "99-swarmd-xbee.rules").read_text().splitlines()
        if line.strip() and not line.startswith("#")
    ]
    assert rules
    for rule in rules:
        pairs = dict(re.findall(r'(\w+(?:\{\w+\})?)[=!+:]?=+"([^"]*)"', rule))
        assert pairs["SUBSYSTEM"] == "tty"
        assert pairs["ATTRS{idVendor}"] == "0403"  # FTDI, Digi's USB adapters
        assert pairs["SYMLINK"] == "xbee"
        assert pairs["GROUP"] == "dialout"


def _tree(root: Path) -> dict[str, tuple[int, str]]:
    out: dict[str, tuple[int, str]] = {}
    for p in sorted(root.rglob("*")):
        st = p.lstat()
        digest = hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else ""
        out[str(p.relative_to(root))] = (st.st_mode, digest)
    return out


def _install(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        ["bash", str(DEPLOY / "install.sh"), *args],
        capture_output=True, text=True, timeout=60, check=True,
    )


def test_install_sh_lays_down_twice_the_same_then_uninstalls(tmp_path: Path) -> None:
    root = tmp_path / "root"
    root.mkdir()
    _install("--root", str(root), "--bin", "/opt/swarmd/bin/swarmd")

    unit = root / "etc/systemd/system/swarmd.service"
    assert "ExecStart=/opt/swarmd/bin/swarmd start --config /etc/swarmd/robot.yaml" in (
        unit.read_text()
    )
    assert (root / "etc/systemd/system/swarmd@.service").is_file()
    assert (root / "etc/udev/rules.d/99-swarmd-xbee.rules").read_bytes() == (
        DEPLOY / "99-swarmd-xbee.rules"
    ).read_bytes()
    # The unit's Documentation= points at the installed guide.
    doc = "usr/local/share/doc/swarmd/operations.md"
    assert f"Documentation=file:/{doc}" in unit.read_text()
    assert (root / doc).read_bytes() == (REPO / "docs/operations.md").read_bytes()
    sysusers = (root / "usr/lib/sysusers.d/swarmd.conf").read_text()
    assert "u swarmd" in sysusers and "m swarmd dialout" in sysusers
    config = root / "etc/swarmd/robot.yaml"
    assert config.read_bytes() == (DEPLOY / "robot.yaml.example").read_bytes()
    assert config.stat().st_mode & 0o777 == 0o640
    assert (root / "etc/swarmd").stat().st_mode & 0o777 == 0o750
    assert (root / "var/lib/swarmd").stat().st_mode & 0o777 == 0o700
    # The host was not touched: no passwd written into the root by install.sh itself.
    assert not (root / "etc/passwd").exists()

    # Idempotent: the second run changes nothing and says it wrote nothing.
    first = _tree(root)
    again = _install("--root", str(root), "--bin", "/opt/swarmd/bin/swarmd")
    assert _tree(root) == first
    assert "wrote" not in again.stdout

    # An operator's config survives a re-install.
    config.write_text("robot: 7\n")
    _install("--root", str(root), "--bin", "/opt/swarmd/bin/swarmd")
    assert config.read_text() == "robot: 7\n"

    _install("--root", str(root), "--uninstall")
    assert not unit.exists()
    assert not (root / "etc/udev/rules.d/99-swarmd-xbee.rules").exists()
    assert not (root / "usr/lib/sysusers.d/swarmd.conf").exists()
    assert not (root / doc).exists()
    assert config.read_text() == "robot: 7\n"  # kept without --purge
    assert (root / "var/lib/swarmd").is_dir()
    _install("--root", str(root), "--uninstall")  # idempotent too
    _install("--root", str(root), "--uninstall", "--purge")
    assert not (root / "etc/swarmd").exists()
    assert not (root / "var/lib/swarmd").exists()


def test_install_sh_user_declaration_creates_the_user(tmp_path: Path) -> None:
    sysusers = shutil.which("systemd-sysusers")
    if sysusers is None:
        pytest.skip("systemd-sysusers not installed (apt-get install systemd)")
    root = tmp_path / "root"
    root.mkdir()
    _install("--root", str(root), "--bin", "/usr/local/bin/swarmd")
    # What the target system does at boot, here confined to the temporary root.
    subprocess.run([sysusers, "--root", str(root)], capture_output=True, timeout=60, check=True)
    passwd = (root / "etc/passwd").read_text()
    group = (root / "etc/group").read_text()
    assert re.search(r"^swarmd:x:\d+:\d+:[^:]*:/var/lib/swarmd:", passwd, re.M)
    assert re.search(r"^dialout:x:\d+:(.*,)?swarmd(,.*)?$", group, re.M)


def test_install_sh_refuses_nonsense() -> None:
    result = subprocess.run(
        ["bash", str(DEPLOY / "install.sh"), "--bogus"], capture_output=True, text=True,
        timeout=60,
    )
    assert result.returncode == 2
    assert "unknown argument --bogus" in result.stderr
    missing_root = subprocess.run(
        ["bash", str(DEPLOY / "install.sh"), "--root", "/nonexistent-swarmd-root"],
        capture_output=True, text=True, timeout=60,
    )
    assert missing_root.returncode == 2


def test_robot_example_is_a_valid_robot_file(tmp_path: Path) -> None:
    config = pytest.importorskip("swarmd.config")
    paper = REPO / "configs" / "paper.yaml"
    if not paper.exists():
        pytest.skip("configs/paper.yaml not in the tree yet")
    shutil.copy(paper, tmp_path / "swarm.yaml")
    for r in range(1, 7):  # as the example's comments say: keys made beside the swarm
        write_identity(tmp_path / "keys", r)
    robot = tmp_path / "robot.yaml"
    shutil.copy(DEPLOY / "robot.yaml.example", robot)
    loaded = config.load_robot(robot)
    assert loaded.identity_file == tmp_path / "keys" / "robot-1.key"
    assert loaded.robot_id == 1
    assert str(loaded.state_dir) == "/var/lib/swarmd"
    assert os.fspath(loaded.swarm_path) == os.fspath(tmp_path / "swarm.yaml")


def test_install_sh_passes_shellcheck() -> None:
    shellcheck = shutil.which("shellcheck")
    if shellcheck is None:
        pytest.skip("shellcheck not installed (scripts/system-deps.sh installs it)")
    scripts = [DEPLOY / "install.sh", DEPLOY.parent / "scripts" / "system-deps.sh"]
    result = subprocess.run(
        [shellcheck, *map(str, scripts)], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0, result.stdout


HOST_INSTALL = r"""
set -euo pipefail
T="$1"; INSTALL="$2"; BIN="$3"
# Private copies of everything install.sh writes on a host: writes land in $T, and the
# mounts vanish with this namespace. Any failed mount stops here, before install.sh.
for d in etc usr/lib/sysusers.d var/lib var/log usr/local/share; do
  mkdir -p "$T/up/$d" "$T/work/$d"
  mount -t overlay overlay \
    -o "lowerdir=/$d,upperdir=$T/up/$d,workdir=$T/work/$d" "/$d"
done
echo NS-READY
bash "$INSTALL" --bin "$BIN" > "$T/first.out"
bash "$INSTALL" --bin "$BIN" > "$T/second.out"
getent passwd swarmd > "$T/passwd"
id -nG swarmd > "$T/groups"
stat -c '%n %U:%G %a' /etc/swarmd /etc/swarmd/robot.yaml /var/lib/swarmd /var/log/swarmd \
  > "$T/stat"
bash "$INSTALL" --uninstall --purge > "$T/uninstall.out"
if getent passwd swarmd >/dev/null; then echo "user still there" >&2; exit 1; fi
test ! -e /etc/swarmd && test ! -e /etc/systemd/system/swarmd.service
"""


def test_install_sh_on_a_host_in_a_private_mount_namespace(tmp_path: Path) -> None:
    """The host path (root /): user creation, chown, re-run, purge. Run in a private
    mount namespace over overlay copies of /etc, /var/lib, ..., so the real host is
    never written."""
    unshare = shutil.which("unshare")
    if unshare is None or os.geteuid() != 0:
        pytest.skip("needs root and unshare(1) for a private mount namespace")
    script = tmp_path / "host.sh"
    script.write_text(HOST_INSTALL)
    host_before = (Path("/etc/passwd").read_bytes(), Path("/etc/swarmd").exists())
    result = subprocess.run(
        [unshare, "--mount", "--propagation", "private", "bash", str(script), str(tmp_path),
         str(DEPLOY / "install.sh"), "/usr/local/bin/swarmd"],
        capture_output=True, text=True, timeout=60,
    )
    if "NS-READY" not in result.stdout:
        pytest.skip(f"cannot set up a private mount namespace here: {result.stderr[-300:]}")
    assert result.returncode == 0, result.stderr + result.stdout
    assert "created system user swarmd" in (tmp_path / "first.out").read_text()
    second = (tmp_path / "second.out").read_text()
    assert "wrote" not in second and "created" not in second
    assert ":/var/lib/swarmd:" in (tmp_path / "passwd").read_text()
    assert "dialout" in (tmp_path / "groups").read_text().split()
    stats = (tmp_path / "stat").read_text().splitlines()
    assert stats == [
        "/etc/swarmd root:swarmd 750",
        "/etc/swarmd/robot.yaml root:swarmd 640",
        "/var/lib/swarmd swarmd:swarmd 700",
        "/var/log/swarmd swarmd:swarmd 750",
    ]
    assert "removed user swarmd" in (tmp_path / "uninstall.out").read_text()
    # Nothing leaked to the real host.
    assert (Path("/etc/passwd").read_bytes(), Path("/etc/swarmd").exists()) == host_before
