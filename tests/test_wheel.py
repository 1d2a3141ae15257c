"""The lean robot install: the wheel, in a fresh venv without the `sim` extra, runs a robot.

`pip install swarmd` carries the daemon, transports, links and CLI; MuJoCo, plotting and
video come with `swarmd[sim]` (README, "Robot install"). This builds the wheel from a copy
of the tree, installs it into a new venv (no system site packages; the base dependencies
come from the package index, pip's cache makes reruns fast) and runs `swarmd` from there.
"""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from swarms import paper_text

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "configs" / "paper.yaml"
SIM_HINT = "pip install 'swarmd[sim]'"
ROS2_HINT = "pip install 'swarmd[ros2]'"

pytestmark = pytest.mark.slow


def run(cmd: list[str | Path], timeout: float, env: dict[str, str] | None = None,
        cwd: str | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(c) for c in cmd], capture_output=True, text=True,
                          timeout=timeout, check=False, env=env, cwd=cwd)


@pytest.fixture(scope="module")
def venv(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """bin/ of a fresh venv with only the swarmd wheel (and its base dependencies)."""
    if importlib.util.find_spec("build") is None:
        pytest.skip("needs `build` (the dev extra)")
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    # A copy, so the build's scratch (build/, *.egg-info) stays out of the work tree.
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(
        ".git", "build", "dist", "out", "*.egg-info", "__pycache__", ".*_cache", ".venv",
        ".make-stamps"))
    built = run([sys.executable, "-m", "build", "--wheel", "--outdir", tmp / "dist", src],
                timeout=600)
    assert built.returncode == 0, built.stdout[-2000:] + built.stderr[-2000:]
    wheel, = (tmp / "dist").glob("swarmd-*.whl")
    made = run([sys.executable, "-m", "venv", tmp / "venv"], timeout=120)
    assert made.returncode == 0, made.stderr
    bin_dir = tmp / "venv" / "bin"
    # --no-compile: byte-compiling every dependency was half of pip's time; the robot's
    # commands below compile what they import.
    installed = run([bin_dir / "python", "-m", "pip", "install", "-q", "--no-compile", wheel],
                    timeout=600, env=clean_env())
    if installed.returncode != 0 and any(
            s in installed.stderr for s in ("No matching distribution", "Could not find a version",
                                            "NewConnectionError", "Network is unreachable")):
        pytest.skip(f"the package index is unreachable: {installed.stderr[-300:]}")
    assert installed.returncode == 0, installed.stderr[-2000:]
    yield bin_dir


def clean_env() -> dict[str, str]:
    """The environment without anything pointing at this work tree or its packages."""
    env = {k: v for k, v in os.environ.items()
           if k not in {"PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV", "NOTIFY_SOCKET"}}
    return {**env, "PYTHONUNBUFFERED": "1"}


def test_the_sim_extra_is_not_installed(venv: Path) -> None:
    done = run([venv / "python", "-c", "import mujoco"], timeout=60, env=clean_env(), cwd="/")
    assert done.returncode != 0 and "No module named 'mujoco'" in done.stderr
    done = run([venv / "python", "-c", "import swarmd, sys; print(swarmd.__file__)"],
               timeout=60, env=clean_env(), cwd="/")
    assert done.returncode == 0 and str(venv.parent) in done.stdout  # the wheel, not the tree


def test_version(venv: Path) -> None:
    done = run([venv / "swarmd", "--version"], timeout=60, env=clean_env(), cwd="/")
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("swarmd ")


def test_start_runs_one_robot_and_stops_on_sigterm(venv: Path, tmp_path: Path,
                                                   udp_port: int) -> None:
    swarm = tmp_path / "swarm.yaml"
    swarm.write_text(paper_text("none", PAPER))
    events = tmp_path / "events.jsonl"
    config = tmp_path / "robot.yaml"
    config.write_text(
        f"robot: 1\nswarm: {swarm}\n"
        f"transport: {{kind: udp, group: 239.255.77.7, port: {udp_port}, "
        "interface: 127.0.0.1, ttl: 1, loopback: true}\n"
        f"link: {{kind: none}}\nstate_dir: {tmp_path / 'state'}\nevent_log: {events}\n")
    proc = subprocess.Popen([venv / "swarmd", "start", "--config", config],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=clean_env(), cwd="/")
    try:
        end = time.monotonic() + 30
        while not (events.exists() and events.read_text()) and time.monotonic() < end:
            assert proc.poll() is None, proc.communicate(timeout=10)
            time.sleep(0.1)
        time.sleep(2)  # one robot running alone for a while: heartbeats, no partner
        assert proc.poll() is None, proc.communicate(timeout=10)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err[-2000:]
    names = [json.loads(line)["event"] for line in events.read_text().splitlines()]
    assert names[0] == "started" and names[-1] == "stopped", names
    assert any(json.loads(line).get("msg") == "ready" for line in out.splitlines())


def test_sim_without_the_extra_says_what_to_install(venv: Path) -> None:
    done = run([venv / "swarmd", "sim", PAPER, "--duration", "1"], timeout=120,
               env=clean_env(), cwd="/")
    assert done.returncode == 2
    message = done.stderr.strip().splitlines()
    assert len(message) == 1 and SIM_HINT in message[0], done.stderr


def test_ros2_options_without_the_extra_say_what_to_install(venv: Path, tmp_path: Path) -> None:
    done = run([venv / "python", "-c", "import rclpy"], timeout=60, env=clean_env(), cwd="/")
    assert done.returncode != 0  # the lean install has no ROS 2
    done = run([venv / "swarmd", "sim", PAPER, "--link", "ros2", "--no-physics",
                "--duration", "1"], timeout=120, env=clean_env(), cwd="/")
    assert done.returncode == 2
    message = done.stderr.strip().splitlines()
    assert len(message) == 1 and ROS2_HINT in message[0], done.stderr
    swarm = tmp_path / "swarm.yaml"
    swarm.write_text(paper_text("none", PAPER))
    done = run([venv / "swarmd", "monitor", "--swarm", swarm, "--once", "--ros2"],
               timeout=120, env=clean_env(), cwd="/")
    assert done.returncode == 2
    message = done.stderr.strip().splitlines()
    assert len(message) == 1 and ROS2_HINT in message[0], done.stderr
    config = tmp_path / "robot.yaml"
    config.write_text(f"robot: 1\nswarm: {swarm}\nlink: {{kind: ros2}}\n"
                      f"state_dir: {tmp_path / 'state'}\n")
    done = run([venv / "swarmd", "start", "--config", config], timeout=60, env=clean_env(),
               cwd="/")
    assert done.returncode == 1 and ROS2_HINT in done.stdout + done.stderr, done
