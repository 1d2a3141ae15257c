"""Hostile and broken input through the commands a user runs: `swarmd check`, `swarmd
start`, `swarmd keygen`, `swarmd sim --fault`. Each case asserts the exit code, the one
line that says what is wrong, and that nothing hangs (every process has a timeout) or is
lost (a state file is set aside, not deleted; /dev/null stays a device). The robot
link's rows are in tests/test_link.py (a client sending garbage, then good lines).

Big inputs are generated in tmp_path, never committed.
"""

from __future__ import annotations

import importlib.util
import json
import os
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest
from swarms import unsigned_paper

from swarmd.config.swarm_rules import load_swarm
from swarmd.core import wire

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "configs" / "paper.yaml"
TIMEOUT = 60.0  # generous on a loaded machine; a hang is what fails


def swarmd(*args: str, timeout: float = TIMEOUT) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    env.pop("NOTIFY_SOCKET", None)
    return subprocess.run([sys.executable, "-m", "swarmd.cli", *args], capture_output=True,
                          text=True, timeout=timeout, env=env, cwd=ROOT)


def no_traceback(proc: subprocess.CompletedProcess[str]) -> None:
    assert "Traceback" not in proc.stdout + proc.stderr, proc.stdout + proc.stderr


def swarm_text(timing: str = "", robot_one: str = "1") -> str:
    return (f"swarm: {{id: 9}}\n{timing}"
            "functions: {f1: {kind: slot, position: [0, 0, 1]}, "
            "f2: {kind: slot, position: [2, 0, 1]}, f3: {kind: slot, position: [4, 0, 1]}}\n"
            "robots:\n"
            f"  - {{id: {robot_one}, state: active, neighbors: [2, 3]}}\n"
            "  - {id: 2, state: active, neighbors: [1, 3]}\n"
            "  - {id: 3, state: active, neighbors: [1, 2]}\n"
            "  - {id: 4, state: standby, subs: [f1, f2, f3]}\n")


def big_swarm(path: Path, actives: int, standbys: int) -> Path:
    """`actives` robots in a ring (each watched by its two neighbours), `standbys` each
    covering four consecutive slots: the swarm bench/bench_config.py times."""
    spec = importlib.util.spec_from_file_location("bench_config",
                                                  ROOT / "bench" / "bench_config.py")
    assert spec is not None and spec.loader is not None
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    written: Path = bench.write_swarm(path, actives, standbys)
    return written


def billion_laughs() -> str:
    lines = ["swarm: {id: 1}", "a0: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    for i in range(1, 10):
        lines.append(f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]")
    return "\n".join(lines) + "\n"


# -- config files through `swarmd check` ----------------------------------------------

@pytest.mark.parametrize(("content", "message", "code"), [
    (lambda: billion_laughs(), "aliases expand to more than 100,000 nodes", 1),
    (lambda: swarm_text().replace("{id: 9}", "{id: " + "9" * 5000 + "}"),
     "<yaml>: a number of 5000 characters", 1),
    (lambda: "swarm: " + "[" * 1000 + "]" * 1000 + "\n", "nested more than 64 levels", 1),
    # libyaml's composer segfaults (rc 139) near 30,000 nested `[`
    (lambda: "swarm: " + "[" * 30000 + "]" * 30000 + "\n", "nested more than 64 levels", 1),
    (lambda: "a:\n" + "".join(" " * i + "- \n" for i in range(1, 200)),
     "nested more than 64 levels", 1),
    (lambda: swarm_text("timing: {heartbeat_interval: 1.0e-9}\n"),
     "timing.heartbeat_interval: heartbeat_interval 1e-09 s is 1,000,000,000 frames/s "
     "per robot; no radio or CPU carries that", 1),
    (lambda: swarm_text("timing: {t_max: 1.0e308}\n"),
     "timing.t_max: t_max 1e+308 s: a failed robot would go unnoticed", 1),
    (lambda: swarm_text(robot_one="true"), "robots[0].id: input should be a valid integer, "
     "got True", 1),
], ids=["billion-laughs", "int-5000-digits", "nested-1000", "nested-30000-segfault",
        "block-nesting-200", "heartbeat-1e-9", "t_max-1e308", "id-true"])
def test_check_refuses_hostile_config(tmp_path: Path, content: object, message: str,
                                      code: int) -> None:
    assert callable(content)
    path = tmp_path / "swarm.yaml"
    path.write_text(content())
    proc = swarmd("check", str(path))
    no_traceback(proc)
    assert proc.returncode == code, proc.stdout
    lines = [ln for ln in proc.stdout.splitlines() if message in ln]
    assert len(lines) == 1, proc.stdout
    assert lines[0].startswith(f"{path}: ")


def test_check_warns_on_odd_timings(tmp_path: Path) -> None:
    path = tmp_path / "swarm.yaml"
    path.write_text(swarm_text("timing: {heartbeat_interval: 0.01, t_max: 90.0}\n"))
    proc = swarmd("check", str(path))
    no_traceback(proc)
    assert ("timing.heartbeat_interval: warning: heartbeat_interval 0.01 s (100 Hz)"
            in proc.stdout)
    assert "timing.t_max: warning: t_max 90 s" in proc.stdout


@pytest.mark.parametrize("kind", ["fifo", "directory", "dev-zero"])
def test_check_and_start_refuse_a_config_that_is_not_a_regular_file(
        tmp_path: Path, kind: str) -> None:
    if kind == "fifo":
        path = tmp_path / "swarm.yaml"
        os.mkfifo(path)
        what = "is a FIFO, not a regular file"
    elif kind == "directory":
        path = tmp_path / "swarm.yaml"
        path.mkdir()
        what = "is a directory, not a regular file"
    else:
        path = Path("/dev/zero")  # only read (and not even that: refused on fstat)
        what = "is a character device, not a regular file"
    proc = swarmd("check", str(path), timeout=30)
    no_traceback(proc)
    assert proc.returncode == 2
    assert f"{path}: <file>: {what}" in proc.stdout.splitlines()
    proc = swarmd("start", "--config", str(path), timeout=30)
    no_traceback(proc)
    assert proc.returncode == 2
    assert what in proc.stdout + proc.stderr


def test_check_refuses_a_config_above_the_size_cap(tmp_path: Path) -> None:
    path = tmp_path / "swarm.yaml"
    with path.open("w") as fh:
        fh.write(swarm_text())
        fh.write(("# " + "x" * 1021 + "\n") * (9 * 1024))  # 9 MiB of comments
    proc = swarmd("check", str(path), timeout=30)
    no_traceback(proc)
    assert proc.returncode == 2
    assert f"{path}: <file>: is {path.stat().st_size} bytes, above the limit of 8388608" \
        in proc.stdout.splitlines()


def test_check_accepts_ordinary_anchors_and_aliases(tmp_path: Path) -> None:
    path = tmp_path / "swarm.yaml"
    path.write_text(swarm_text().replace("state: standby, subs: [f1, f2, f3]}",
                                         "state: standby, subs: &all [f1, f2, f3]}\n"
                                         "  - {id: 5, state: standby, subs: *all}"))
    proc = swarmd("check", str(path), timeout=30)
    no_traceback(proc)
    assert proc.returncode == 0, proc.stdout
    assert proc.stdout.splitlines()[-1].startswith(f"{path}: usable, with ")


def test_check_refuses_a_key_file_that_is_a_fifo(tmp_path: Path) -> None:
    os.mkfifo(tmp_path / "swarm.key")
    path = tmp_path / "swarm.yaml"
    path.write_text(swarm_text().replace("swarm: {id: 9}\n",
                                         "swarm: {id: 9}\nkey_file: swarm.key\n"))
    proc = swarmd("check", str(path), timeout=30)
    no_traceback(proc)
    assert proc.returncode == 1
    assert "key_file: key file" in proc.stdout and "is a FIFO, not a regular file" in proc.stdout


def test_check_of_a_5255_robot_swarm_is_linear(tmp_path: Path) -> None:
    """255 actives + 5,000 standbys: the load time is printed (bench/bench_config.py
    measures it); a quadratic coverage would take minutes and hit the timeout."""
    path = big_swarm(tmp_path / "big.yaml", 255, 5000)
    t0 = time.perf_counter()
    cfg = load_swarm(path)
    rows = cfg.coverage()
    elapsed = time.perf_counter() - t0
    print(f"\nload + coverage of 5,255 robots: {elapsed:.2f} s")
    assert len(cfg.robots) == 5255
    assert all(len(r.holders) == 1 and len(r.watchers) == 2 for r in rows)
    assert sum(len(r.standbys) for r in rows) == 5000 * 4  # each standby covers four
    proc = swarmd("check", str(path), "--json", timeout=120)
    no_traceback(proc)
    assert proc.returncode == 0, proc.stdout[-2000:]


# -- state files through `swarmd start` -----------------------------------------------

def state_cases() -> dict[str, str]:
    good = {"version": 1, "robot": 2, "swarm": 1543, "known": {"f2": [2, 0]},
            "held": None, "seq_reserved": 0}
    return {
        "held-epoch-70000": json.dumps({**good, "held": ["f2", 70000]}),
        "known-epoch-70000": json.dumps({**good, "known": {"f2": [2, 70000]}}),
        "nested-100k": "[" * 100_000 + "]" * 100_000,
        "int-5000-digits": json.dumps(good).replace('"seq_reserved": 0',
                                                    '"seq_reserved": ' + "7" * 5000),
        "seq-above-2^48": json.dumps({**good, "seq_reserved": wire.SEQ_MAX + 1}),
        "unknown-holder": json.dumps({**good, "known": {"f2": [77, 3]}}),
    }


@pytest.mark.slow
@pytest.mark.parametrize("case", list(state_cases()))
def test_start_sets_aside_an_unusable_state_file_and_starts_fresh(
        tmp_path: Path, case: str, udp_port: int) -> None:
    state_dir = tmp_path / "state"
    state_dir.mkdir()
    state = state_dir / "swarm1543-robot2.json"
    state.write_text(state_cases()[case])
    original = state.read_bytes()
    # Interrupted atomic writes of this robot, and one of another robot sharing the dir.
    stale = [state_dir / f".swarm1543-robot2.json.x{i}.tmp" for i in range(3)]
    for p in stale:
        p.write_text("{")
    other = state_dir / ".swarm1543-robot3.json.x0.tmp"
    other.write_text("{")
    config = tmp_path / "robot.yaml"
    config.write_text(f"robot: 2\nswarm: {unsigned_paper(tmp_path)}\n"
                      f"transport: {{kind: udp, port: {udp_port}}}\n"
                      f"state_dir: {state_dir}\n")
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    env.pop("NOTIFY_SOCKET", None)
    proc = subprocess.Popen([sys.executable, "-m", "swarmd.cli", "start", "--config",
                             str(config)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env)
    records: list[dict[str, object]] = []
    try:
        assert proc.stdout is not None
        deadline = time.monotonic() + TIMEOUT
        for line in proc.stdout:
            records.append(json.loads(line))
            if records[-1]["msg"] in ("ready", "daemon failed to start"):
                break
            assert time.monotonic() < deadline
        proc.terminate()
        _, err = proc.communicate(timeout=TIMEOUT)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    msgs = [r["msg"] for r in records]
    assert "ready" in msgs, (records, err)
    assert "Traceback" not in err
    unusable = [r for r in records if r["msg"] == "state file unusable; starting fresh"]
    assert len(unusable) == 1, records  # one logged line
    moved = sorted(state_dir.glob("swarm1543-robot2.json.corrupt-*"))
    assert len(moved) == 1 and moved[0].read_bytes() == original  # set aside, not lost
    assert proc.returncode == 0
    assert not any(p.exists() for p in stale) and other.exists()
    fresh = json.loads(state.read_text())  # the fresh start wrote a good file
    assert fresh["held"] in (None, ["f2", 0])  # robot 2 starts as configured
    assert all(0 <= e <= 0xFFFF for _, e in fresh["known"].values())
    assert set(fresh["known"]) <= {"f1", "f2", "f3", "f4"}
    assert 0 < fresh["seq_reserved"] <= wire.SEQ_MAX


# -- keygen ----------------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["fifo", "device-symlink", "directory"])
def test_keygen_force_writes_only_regular_files(tmp_path: Path, kind: str) -> None:
    path = tmp_path / "swarm.key"
    null_before = os.stat("/dev/null")
    if kind == "fifo":
        os.mkfifo(path)
        what = "is a FIFO"
    elif kind == "device-symlink":
        path.symlink_to("/dev/null")  # never a real device node of our own
        what = "is a character device"
    else:
        path.mkdir()
        what = "is a directory"
    proc = swarmd("keygen", str(path), "--force", timeout=30)
    no_traceback(proc)
    assert proc.returncode == 1
    assert proc.stderr.strip().splitlines() == [
        f"swarmd keygen: {path} {what}, not a regular file; refusing to replace it "
        "(even with --force)"]
    mode = os.lstat(path).st_mode
    assert {"fifo": stat.S_ISFIFO, "device-symlink": stat.S_ISLNK,
            "directory": stat.S_ISDIR}[kind](mode)
    null_after = os.stat("/dev/null")
    assert stat.S_ISCHR(null_after.st_mode) and null_after.st_rdev == null_before.st_rdev
    assert not list(tmp_path.glob(".*.tmp"))


def test_keygen_force_still_replaces_a_regular_key(tmp_path: Path) -> None:
    path = tmp_path / "swarm.key"
    path.write_bytes(b"x" * 32)
    proc = swarmd("keygen", str(path), "--force", timeout=30)
    assert proc.returncode == 0, proc.stderr
    assert len(path.read_bytes()) == 32 and path.read_bytes() != b"x" * 32


# -- fault specs -----------------------------------------------------------------------

@pytest.mark.parametrize(("spec", "message"), [
    ("crash:" + "9" * 5000 + "@1", "is not a robot id (1..65535)"),
    ("crash:2@" + "9" * 5000, "time T"),
])
def test_sim_refuses_a_fault_with_a_huge_number(spec: str, message: str) -> None:
    proc = swarmd("sim", str(PAPER), "--virtual", "--fault", spec, timeout=30)
    no_traceback(proc)
    assert proc.returncode == 2
    lines = [ln for ln in (proc.stdout + proc.stderr).splitlines() if message in ln]
    assert len(lines) == 1 and len(lines[0]) < 300, proc.stderr


@pytest.mark.parametrize(("swarm", "message"), [
    (billion_laughs, "aliases expand to more than 100,000 nodes"),
    (lambda: "swarm: " + "[" * 30000 + "]" * 30000 + "\n", "nested more than 64 levels"),
], ids=["billion-laughs", "nested-30000-segfault"])
def test_start_refuses_a_hostile_swarm_file_at_once(tmp_path: Path, swarm: object,
                                                    message: str) -> None:
    assert callable(swarm)
    (tmp_path / "swarm.yaml").write_text(swarm())
    config = tmp_path / "robot.yaml"
    config.write_text("robot: 1\nswarm: swarm.yaml\ntransport: {kind: udp}\n"
                      f"state_dir: {tmp_path / 'state'}\n")
    proc = swarmd("start", "--config", str(config), timeout=30)
    no_traceback(proc)
    assert proc.returncode == 2
    assert message in proc.stdout + proc.stderr
    assert not (tmp_path / "state").exists()  # refused before anything was set up


# -- import-launch: its input and its -o output ----------------------------------------

LAUNCH = ROOT / "tests" / "fixtures" / "paper.launch"


@pytest.mark.parametrize("kind", ["fifo", "device-symlink", "directory", "no-parent"])
def test_import_launch_checks_its_output_before_anything_runs(tmp_path: Path,
                                                              kind: str) -> None:
    out = tmp_path / "swarm.yaml"
    what = {"fifo": "it is a FIFO, not a regular file",
            "device-symlink": "it is a character device, not a regular file",
            "directory": "it is a directory, not a regular file",
            "no-parent": "does not exist"}[kind]
    if kind == "fifo":
        os.mkfifo(out)
    elif kind == "device-symlink":
        out.symlink_to("/dev/null")
    elif kind == "directory":
        out.mkdir()
    else:
        out = tmp_path / "missing" / "swarm.yaml"
    proc = swarmd("import-launch", str(LAUNCH), "-o", str(out), timeout=30)
    no_traceback(proc)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"{out}: cannot write: ") and what in lines[0]


def test_import_launch_refuses_a_fifo_as_launch_file(tmp_path: Path) -> None:
    fifo = tmp_path / "paper.launch"
    os.mkfifo(fifo)
    proc = swarmd("import-launch", str(fifo), timeout=30)
    no_traceback(proc)
    assert proc.returncode == 2
    assert proc.stderr.strip() == f"{fifo}: cannot read the file: is a FIFO, not a regular file"
