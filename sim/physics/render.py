"""Render a run: replay every robot's recorded trajectory in one MuJoCo scene.

N crafts are mocap bodies (no physics here: the flying already happened in the robot
processes), each coloured by its role at that instant from the event log (the same
spans as the timeline: active green, standby grey, claiming orange, fenced red, crashed
black). A fixed camera sees the whole swarm; 640x480, shadows and reflections off and
`offsamples=0` (about 20 ms a frame instead of 100-140 ms, docs/physics.md). Output:
`swarm.mp4` (imageio-ffmpeg's bundled ffmpeg) or `swarm.gif` when that fails, and key
frames `key-*.png` at the faults and takeovers. Every frame names each craft's robot and
function; a key frame rings the robots its event is about (sim/physics/labels.py).

MuJoCo picks its GL backend when it is imported (`MUJOCO_GL`), and a robot or test
process has usually imported it already without one; so rendering always runs in a
child process (`python -m sim.physics.render JOB`) with `MUJOCO_GL` set to a backend that
`gl_available()` proved loads (egl, then osmesa).
"""

from __future__ import annotations

import functools
import json
import math
import os
import subprocess
import sys
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sim.physics.labels import KeyMoment, View, annotate, craft_labels, key_moments
from sim.physics.plots import ROLE_COLORS, Span, role_at, role_spans
from sim.physics.robot import Trajectory
from sim.shared.faults import FaultKind
from swarmd.core.events import Fault, event_of

BACKENDS = ("egl", "osmesa")
WIDTH, HEIGHT = 640, 480
KEY_EVENTS = ("fault", "takeover")

_PROBE = """
import mujoco
m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom size="1"/></worldbody></mujoco>')
r = mujoco.Renderer(m, 32, 32)
r.update_scene(mujoco.MjData(m))
img = r.render()
assert img.shape == (32, 32, 3)
"""


def _gl_env(backend: str) -> dict[str, str]:
    env = dict(os.environ)
    env["MUJOCO_GL"] = backend
    env["PYOPENGL_PLATFORM"] = backend
    return env


@functools.cache
def gl_available() -> tuple[bool, str]:
    """(True, backend) for the first headless GL backend that renders a frame in a
    child process, else (False, why each failed)."""
    tried = []
    first = os.environ.get("MUJOCO_GL")
    for backend in ((first,) if first in BACKENDS else ()) + BACKENDS:
        try:
            proc = subprocess.run(
                [sys.executable, "-c", _PROBE], env=_gl_env(backend),
                capture_output=True, text=True, timeout=60,
            )
        except (OSError, subprocess.TimeoutExpired) as exc:
            tried.append(f"{backend}: {exc}")
            continue
        if proc.returncode == 0:
            return True, backend
        last = (proc.stderr.strip().splitlines() or [f"exit {proc.returncode}"])[-1]
        tried.append(f"{backend}: {last}")
    return False, "no headless GL backend loads (" + "; ".join(tried) + ")"


@dataclass(slots=True)
class RenderResult:
    """What `render_swarm` wrote."""

    video: Path | None = None
    keyframes: list[Path] = field(default_factory=list)
    frames: int = 0
    backend: str | None = None
    error: str | None = None
    """Why no video was made (no GL backend, the child failed), else None."""
    labels: dict[Path, list[dict[str, Any]]] = field(default_factory=dict)
    """Per key frame, the crafts' labels as drawn: robot, text, pixel box and the
    craft's pixel `at` (sim.physics.labels.Placed)."""


def key_times(events: Sequence[Mapping[str, Any]]) -> list[tuple[float, str]]:
    """(t, label) of the moments worth a still: faults and takeovers."""
    return [(m.t, m.name) for m in key_moments(events)]


def render_swarm(
    trajectories: Sequence[Trajectory],
    events: Sequence[Mapping[str, Any]],
    out_dir: Path,
    *,
    fps: int = 20,
    speed: float = 1.0,
    start: float | None = None,
    end: float | None = None,
    keyframes: bool = True,
    fmt: str = "mp4",
    preset_name: str = "x2",
    timeout: float = 600.0,
) -> RenderResult:
    """Render the swarm from `start` to `end` (run seconds; default: the recorded span)
    at `fps` frames per second of video, `speed` seconds of run per second of video.
    Never raises for a missing backend or a failed child: see `RenderResult.error`."""
    ok, backend = gl_available()
    if not ok:
        return RenderResult(error=backend)
    if not trajectories:
        return RenderResult(error="no trajectories to render")
    out_dir.mkdir(parents=True, exist_ok=True)
    t_lo = start if start is not None else min(float(tr.t[0]) for tr in trajectories)
    t_hi = end if end is not None else max(float(tr.t[-1]) for tr in trajectories)
    job = {
        "robots": [tr.robot for tr in trajectories],
        "events": [dict(e) for e in events],
        "out_dir": str(out_dir),
        "fps": fps,
        "speed": speed,
        "start": t_lo,
        "end": t_hi,
        "keyframes": keyframes,
        "fmt": fmt,
        "preset": preset_name,
    }
    return _render_in_child(job, trajectories, backend, timeout)


def _render_in_child(job: dict[str, Any], trajectories: Sequence[Trajectory], backend: str,
                     timeout: float) -> RenderResult:
    """Run the render child on `job` and the trajectories (written to a temporary
    directory for it): what it rendered, or why not."""
    with tempfile.TemporaryDirectory(prefix="swarmd-render-") as tmp:
        arrays: dict[str, Any] = {}
        for i, tr in enumerate(trajectories):
            arrays[f"t{i}"], arrays[f"p{i}"], arrays[f"q{i}"] = tr.t, tr.pos, tr.quat
        np.savez(Path(tmp) / "traj.npz", **arrays)
        job = {**job, "traj": str(Path(tmp) / "traj.npz")}
        job_path = Path(tmp) / "job.json"
        job_path.write_text(json.dumps(job))
        try:
            proc = subprocess.run(
                [sys.executable, "-m", "sim.physics.render", str(job_path)], env=_gl_env(backend),
                capture_output=True, text=True, timeout=timeout,
            )
        except subprocess.TimeoutExpired:
            return RenderResult(backend=backend, error=f"render took over {timeout:.0f} s")
    return _result_of(proc, backend)


def _result_of(proc: subprocess.CompletedProcess[str], backend: str) -> RenderResult:
    """What the render child reported: its video and key frames, or why it failed."""
    if proc.returncode != 0:
        tail = " | ".join(proc.stderr.strip().splitlines()[-3:])
        return RenderResult(backend=backend, error=f"render child failed: {tail}")
    done = json.loads(proc.stdout.strip().splitlines()[-1])
    return RenderResult(
        video=Path(done["video"]) if done.get("video") else None,
        keyframes=[Path(p) for p in done["keyframes"]],
        frames=int(done["frames"]),
        backend=backend,
        error=done.get("error"),
        labels={Path(k): v for k, v in done.get("labels", {}).items()},
    )


def trajectory_files(report_dir: Path) -> list[Path]:
    """The robots' trajectory files a real-time run left under `report_dir`
    (`realtime/state/<id>/traj-<id>.jsonl`, written by `sim.physics.link.QuadLink`)."""
    return sorted(report_dir.glob("realtime/state/*/traj-*.jsonl"))


def run_origin(paths: Sequence[Path]) -> float | None:
    """The run's t0 (Unix time) as the trajectory headers tell it: every robot's link
    starts when its daemon does, at t0, so the earliest header `wall0` is t0 to within
    the start-up jitter (milliseconds). None if no header says."""
    origins = []
    for path in paths:
        try:
            with path.open() as f:
                head = json.loads(f.readline())
        except (OSError, ValueError):
            continue
        if isinstance(head, dict) and head.get("wall0") is not None:
            origins.append(float(head["wall0"]))
    return min(origins) if origins else None


def report_pictures(
    report_dir: Path,
    events: Sequence[Mapping[str, Any]],
    functions: Mapping[str, Mapping[str, Any]] | None = None,
    *,
    t0: float | None = None,
    end: float | None = None,
    video: bool = True,
    fps: int = 20,
    speed: float = 1.0,
) -> dict[str, Any]:
    """The physics pictures of `swarmd sim --report DIR`, from the
    trajectory files the robots wrote: `trajectories.png` always, and where a GL backend
    loads `swarm.mp4` (or `.gif`) and `key-*.png`. Returns what was written, and why
    not (`"video_error"`); never raises for a robot's broken trajectory file."""
    from sim.physics.plots import trajectory_png

    paths = trajectory_files(report_dir)
    origin = t0 if t0 is not None else run_origin(paths)
    out: dict[str, Any] = {"trajectories": len(paths)}
    trajs = _load_trajectories(paths, origin, out)
    if not trajs:
        out["video_error"] = ("no trajectory files under realtime/state/ (a run without "
                              "physics, or one stopped before the robots flew)")
        return out
    trajs = [_with_fall(tr, events) for tr in trajs]
    out["trajectory_png"] = trajectory_png(trajs, report_dir / "trajectories.png", functions)
    if video:
        res = render_swarm(trajs, events, report_dir, fps=fps, speed=speed,
                           start=0.0, end=end)
        out.update(video=res.video, keyframes=res.keyframes, frames=res.frames,
                   backend=res.backend)
        if res.error:
            out["video_error"] = res.error
    return out


def _load_trajectories(paths: Sequence[Path], origin: float | None,
                       out: dict[str, Any]) -> list[Trajectory]:
    """The trajectories that load; each that does not is listed in `out["skipped"]`."""
    from sim.physics.robot import load_trajectory

    trajs = []
    for path in paths:
        try:
            trajs.append(load_trajectory(path, t0=origin))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            out.setdefault("skipped", []).append(f"{path.name}: {exc}")
    return trajs


FALL_STEP = 0.05
"""s between the samples of a drawn fall."""


def _with_fall(tr: Trajectory, events: Sequence[Mapping[str, Any]]) -> Trajectory:
    """A robot whose process was killed (`crash`, or a `restart` it did not come back
    from) stops writing its trajectory in mid-air. For the pictures only, its craft
    falls from the last sample to the ground (free fall, level) and lies there
    "crashed", instead of hanging black where it was. Nothing else is changed: the
    physics of a dead process is unknown, this is a drawing."""
    if len(tr.t) == 0:
        return tr
    last = float(tr.t[-1])
    # Killed where the samples end (a restarted robot's samples go on after its kill).
    killed = any(isinstance(ev := event_of(e), Fault) and e.get("robot") == tr.robot
                 and ev.kind in (FaultKind.CRASH, FaultKind.RESTART)
                 and abs(float(e.get("t", 0.0)) - last) <= 0.5 for e in events)
    if not killed or (tr.modes and tr.modes[-1] in ("parked", "crashed")):
        return tr
    ground = float(tr.pos[0][2])  # it started parked on the ground at home
    z0 = float(tr.pos[-1][2])
    fall = math.sqrt(max(0.0, 2.0 * (z0 - ground) / 9.81))
    steps = max(1, math.ceil(fall / FALL_STEP))
    ts = [last + fall * (k + 1) / steps for k in range(steps)]
    pos = [(tr.pos[-1][0], tr.pos[-1][1], max(ground, z0 - 4.905 * (t - last) ** 2))
           for t in ts]
    return Trajectory(
        tr.robot,
        np.concatenate([tr.t, np.array(ts)]),
        np.concatenate([tr.pos, np.array(pos)]),
        np.concatenate([tr.quat, np.repeat(tr.quat[-1:], steps, axis=0)]),
        (*tr.modes, *("crashed",) * steps) if tr.modes else tr.modes,
        (*tr.functions, *(None,) * steps) if tr.functions else tr.functions,
        tr.home,
    )


# -- the child ----------------------------------------------------------------------------


def _rgba(hex_colour: str) -> tuple[float, float, float, float]:
    h = hex_colour.lstrip("#")
    return (int(h[0:2], 16) / 255, int(h[2:4], 16) / 255, int(h[4:6], 16) / 255, 1.0)


class _Scene:
    """The replay scene and its renderer (child process only: needs MUJOCO_GL)."""

    def __init__(self, trajs: list[Trajectory], preset_name: str) -> None:
        import mujoco

        from sim.physics.model import preset, scene_xml

        self.mj = mujoco
        self.trajs = trajs
        lo = np.min([tr.pos.min(axis=0) for tr in trajs], axis=0)
        hi = np.max([tr.pos.max(axis=0) for tr in trajs], axis=0)
        extent = float(max(hi[0] - lo[0], hi[1] - lo[1], 4.0))
        self.model = mujoco.MjModel.from_xml_string(
            scene_xml(preset(preset_name), len(trajs), extent=extent + 10.0)
        )
        self.data = mujoco.MjData(self.model)
        self.mocap = [
            int(self.model.body_mocapid[self.model.body(f"quad{i + 1}").id])
            for i in range(len(trajs))
        ]
        self.hull = [self.model.geom(f"quad{i + 1}_hull").id for i in range(len(trajs))]
        self.renderer = mujoco.Renderer(self.model, HEIGHT, WIDTH)
        flags = self.renderer.scene.flags
        flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
        flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        centre = (lo + hi) / 2
        cam.lookat[:] = (centre[0], centre[1], max(0.5, centre[2]))
        cam.distance = 0.95 * extent + 3.0
        cam.azimuth = -90.0 + 30.0
        cam.elevation = -35.0
        self.camera = cam

    def frame(self, t: float, spans: Mapping[int, Sequence[Span]]) -> np.ndarray[Any, Any]:
        """The crafts at run time `t`, coloured by role (no words: see `labelled`)."""
        for i, tr in enumerate(self.trajs):
            pos, quat = tr.at(t)
            self.data.mocap_pos[self.mocap[i]] = pos
            self.data.mocap_quat[self.mocap[i]] = quat
            span = role_at(spans.get(tr.robot, ()), t)
            role = span.role if span is not None else "standby"
            self.model.geom_rgba[self.hull[i]] = _rgba(ROLE_COLORS.get(role, "#cccccc"))
        self.mj.mj_kinematics(self.model, self.data)
        self.renderer.update_scene(self.data, camera=self.camera)
        flags = self.renderer.scene.flags
        flags[self.mj.mjtRndFlag.mjRND_SHADOW] = 0
        flags[self.mj.mjtRndFlag.mjRND_REFLECTION] = 0
        img: np.ndarray[Any, Any] = self.renderer.render()
        return img

    def labelled(self, t: float, spans: Mapping[int, Sequence[Span]], header: str,
                 moment: KeyMoment | None = None) -> tuple[np.ndarray[Any, Any], list[Any]]:
        """`frame` with each craft's robot id and function beside it, rings and a
        caption when it is `moment`'s still (sim/physics/labels.py); and the labels'
        boxes."""
        img = self.frame(t, spans)
        view = View.of(self.renderer.scene.camera[0], WIDTH, HEIGHT)
        pixels = [view.pixel(tr.at(t)[0]) for tr in self.trajs]
        labels = craft_labels([tr.robot for tr in self.trajs], spans, t, moment)
        return annotate(img, header, labels, pixels,
                        moment.caption if moment is not None else None)


def _write_video(frames: list[np.ndarray[Any, Any]], out_dir: Path, fps: int, fmt: str) -> Path:
    if fmt == "mp4":
        try:
            import imageio.v2 as imageio

            path = out_dir / "swarm.mp4"
            with imageio.get_writer(path, fps=fps, codec="libx264", quality=7,
                                    macro_block_size=16) as w:
                for f in frames:
                    w.append_data(f)  # type: ignore[attr-defined]
            return path
        except Exception as exc:  # no ffmpeg: fall back to a GIF (still a moving picture)
            print(f"mp4 failed ({exc}); writing a GIF", file=sys.stderr)
    from PIL import Image

    path = out_dir / "swarm.gif"
    ims = [Image.fromarray(f).quantize(colors=128) for f in frames]
    ims[0].save(path, save_all=True, append_images=ims[1:], duration=int(1000 / fps), loop=0)
    return path


def _child(job_path: Path) -> dict[str, Any]:
    job = json.loads(job_path.read_text())
    arrays = np.load(job["traj"])
    trajs = [
        Trajectory(rid, arrays[f"t{i}"], arrays[f"p{i}"], arrays[f"q{i}"], (), ())
        for i, rid in enumerate(job["robots"])
    ]
    out_dir = Path(job["out_dir"])
    events = job["events"]
    spans = role_spans(events, end=job["end"])
    scene = _Scene(trajs, job["preset"])
    fps = int(job["fps"])
    speed = float(job["speed"])
    t_lo, t_hi = float(job["start"]), float(job["end"])
    n = max(1, math.floor((t_hi - t_lo) * fps / speed) + 1)
    frames = []
    for k in range(n):
        t = t_lo + k * speed / fps
        frames.append(scene.labelled(t, spans, f"t = {t:5.1f} s")[0])
    video = _write_video(frames, out_dir, fps, job["fmt"])
    labels = _keyframes(scene, spans, events, out_dir, t_lo, t_hi) if job["keyframes"] else {}
    return {"video": str(video), "keyframes": list(labels), "frames": len(frames),
            "labels": labels}


def _keyframes(scene: _Scene, spans: Mapping[int, Sequence[Span]],
               events: Sequence[Mapping[str, Any]], out_dir: Path, t_lo: float,
               t_hi: float) -> dict[str, list[dict[str, Any]]]:
    """The stills `key-<t>-<name>.png` at the start, each fault and takeover (its robots
    ringed) and the end; per still, its labels (robot, text, box)."""
    from PIL import Image

    moments = [KeyMoment(t_lo, "start", ""), *key_moments(events),
               KeyMoment(t_hi, "end", "")]
    out: dict[str, list[dict[str, Any]]] = {}
    for m in moments:
        if not t_lo <= m.t <= t_hi:
            continue
        # A still a little after the event shows its effect (the substitute leaving).
        shot = min(t_hi, m.t + (0.5 if m.name not in ("start", "end") else 0.0))
        path = out_dir / f"key-{shot:07.2f}-{m.name}.png"
        img, placed = scene.labelled(shot, spans, f"t = {shot:5.1f} s  {m.name}", m)
        Image.fromarray(img).save(path)
        out[str(path)] = [{"robot": p.robot, "text": p.text, "box": list(p.box),
                           "at": list(p.at)} for p in placed]
    return out


if __name__ == "__main__":
    print(json.dumps(_child(Path(sys.argv[1]))))
