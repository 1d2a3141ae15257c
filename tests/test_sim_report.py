"""`swarmd sim --report DIR` end to end, as `make demo` runs it.

One flown run of the paper's swarm with robot 2 crashing, through the CLI in a
subprocess (the forkserver, `-m swarmd.cli` and the report writing are what a user
runs), shared by the tests below; plus one short bare run into a reused directory.
The video test skips with the reason only where no headless GL backend loads (CI
installs one: scripts/system-deps.sh).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import pytest
from PIL import Image
from test_event_contract import check_records

from sim.physics.render import gl_available
from swarmd.config import load_swarm
from swarmd.services.state import state_path

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "configs" / "paper.yaml"
DURATION = 8.0

pytestmark = pytest.mark.slow


def _sim(*args: str, timeout: float, cwd: Path = ROOT) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "swarmd.cli", "sim", str(PAPER), *args],
                          cwd=cwd, capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def flown(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, object], str]:
    # A relative --report, as `make demo` gives it: the robots must still write their
    # trajectories into it (they once went under realtime/robots/<report>/).
    here = tmp_path_factory.mktemp("cwd")
    report = here / "out" / "demo"
    proc = _sim("--fault", "crash:2@3", "--duration", str(DURATION), "--report", "out/demo",
                "--json", timeout=DURATION + 150, cwd=here)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return report, json.loads(proc.stdout), proc.stderr


def _png(path: Path) -> tuple[int, int]:
    with Image.open(path) as im:
        assert im.format == "PNG"
        size: tuple[int, int] = im.size
        return size


def test_flown_report_has_summary_events_timeline_and_trajectories(
        flown: tuple[Path, dict[str, object], str]) -> None:
    report, summary, stderr = flown
    faults = summary["faults"]
    assert isinstance(faults, list) and len(faults) == 1
    assert faults[0]["taken_over_by"] == 6 and faults[0]["function"] == "f2"
    assert json.loads((report / "summary.json").read_text())["faults"] == faults
    events = [json.loads(line) for line in (report / "events.jsonl").read_text().splitlines()]
    assert any(e["event"] == "takeover" and e["robot"] == 6 for e in events)
    check_records(events)  # DESIGN section 3's names and fields only
    assert _png(report / "timeline.png")[0] > 0
    assert _png(report / "trajectories.png")[0] > 0
    # Every robot flew (or stood parked) with its own physics and left a trajectory.
    assert len(list(report.glob("realtime/state/*/traj-*.jsonl"))) == 6
    # The user is told what was written.
    assert "report:" in stderr and "trajectories.png" in stderr


def test_flown_report_has_a_video_and_key_frames(
        flown: tuple[Path, dict[str, object], str]) -> None:
    ok, why = gl_available()
    if not ok:
        pytest.skip(why)
    report, _, stderr = flown
    assert "no video" not in stderr, stderr[-2000:]
    video = report / "swarm.mp4"
    frames = iio.imread(video, index=None)
    assert frames.shape[0] >= DURATION * 10 and frames.shape[1:] == (480, 640, 3)
    keys = sorted(p.name for p in report.glob("key-*.png"))
    # start, robot 2's crash, robot 6's takeover of f2, end
    assert len(keys) == 4, keys
    assert "fault-crash-r2" in keys[1] and "takeover-f2-r6" in keys[2]
    for name in keys:
        assert _png(report / name) == (640, 480)


def test_a_reused_report_directory_starts_a_fresh_run(tmp_path: Path) -> None:
    # What an earlier run left: robot 6's persisted state and trajectory from a run in
    # which it held f2, an old key frame; and a file of the user's.
    old = tmp_path / "realtime" / "state" / "6"
    old.mkdir(parents=True)
    swarm_id = load_swarm(PAPER).swarm.id
    state_path(old, swarm_id, 6).write_text(json.dumps({
        "version": 1, "robot": 6, "swarm": swarm_id, "known": {"f2": [6, 1]},
        "held": ["f2", 1], "seq_reserved": 10**12}))
    (old / "traj-6.jsonl").write_text("{}\n")
    (tmp_path / "key-0009.00-takeover-f2-r6.png").write_bytes(b"old")
    (tmp_path / "notes.txt").write_text("mine")
    proc = _sim("--no-physics", "--duration", "2", "--report", str(tmp_path), "--json",
                timeout=60)
    assert proc.returncode == 0, proc.stderr[-2000:]
    records = [json.loads(x) for x in (tmp_path / "events.jsonl").read_text().splitlines()]
    started = {e["robot"]: (e["role"], e["function"]) for e in records
               if e["event"] == "started"}
    assert started == {1: ("active", "f1"), 2: ("active", "f2"), 3: ("active", "f3"),
                       4: ("active", "f4"), 5: ("standby", None), 6: ("standby", None)}
    # The end of the run stops every robot: each log ends with `stopped`.
    last = {e["robot"]: e["event"] for e in records}
    assert last == {r: "stopped" for r in range(1, 7)}
    assert not (old / "traj-6.jsonl").exists()
    assert not list(tmp_path.glob("key-*.png"))
    assert (tmp_path / "notes.txt").read_text() == "mine"


def test_report_that_is_a_file_is_refused(tmp_path: Path) -> None:
    target = tmp_path / "report"
    target.write_text("not a directory")
    proc = _sim("--virtual", "--duration", "1", "--report", str(target), timeout=60)
    assert proc.returncode == 2
    assert "not a directory" in proc.stderr
    assert target.read_text() == "not a directory"


def test_craft_chooses_the_quadrotor_every_robot_flies(tmp_path: Path) -> None:
    # The report renders a video: 10 s on a quiet machine, over 90 s seen at load 20; the
    # timeout only stops a hang.
    proc = _sim("--craft", "crazyflie", "--duration", "2", "--report", str(tmp_path),
                "--json", timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    headers = [json.loads(p.read_text().splitlines()[0])
               for p in tmp_path.glob("realtime/state/*/traj-*.jsonl")]
    assert len(headers) == 6 and {h["preset"] for h in headers} == {"crazyflie"}


def test_an_unknown_craft_is_refused_naming_the_known_ones() -> None:
    proc = _sim("--craft", "x9", "--duration", "2", timeout=60)
    assert proc.returncode == 2
    assert "'x9'" in proc.stderr and "crazyflie" in proc.stderr and "x2" in proc.stderr
