"""swarmd against SWIM, side by side on loopback: swim-protocol 0.6.3 (the asyncio SWIM
library on PyPI) and swarmd, 5 members each, at equal datagrams per member per second.

    python bench/bench_peers.py            # 10 crashes per system, rate and channel, 120 s
    python bench/bench_peers.py --quick    # 3 crashes, 30 s windows (a quarter of an hour)
    python bench/bench_peers.py --channel "30% bursts of 8"   # one lossy channel only

What is compared, per rate (about 2 and 8 datagrams per member per second):
- crash -> detection, SWIM: a member is SIGKILLed; time until the first survivor marks
  it OFFLINE (swim-protocol's on-update notification, the hook its sync tool runs);
- crash -> takeover, swarmd: five real daemon processes (the code `swarmd start` runs,
  through `sim.realtime`, as `swarmd sim --no-physics`), robots 1-4 active in a ring and
  standby 5 covering all four; robot 2 is SIGKILLed; time until its function is taken
  over (the standby's CLAIM won and it heartbeats the function). Detection (the first
  WARN) is printed too;
- datagrams and UDP payload bytes per member per second, measured in steady state before
  the crash: SWIM counts in each member what it sends, swarmd by a passive listener on
  the multicast group (one heartbeat is one datagram for every neighbour);
- false detections over a window with no crash on a lossy channel: SWIM's OFFLINE marks
  of live members (summed over observers) and SUSPECT marks; swarmd's false takeovers
  and false suspicions (`swarmd sim` summary).

Channels (`CHANNELS`): clean, then the same loss patterns for both systems, drawn per
receiver: 20 % independent losses, and Gilbert-Elliott bursts per sender and receiver
(`--loss-model burst`, sim/shared/channel.py; `swim_member.py --burst-len` for SWIM) of
8 datagrams at 30 % and of 4 at 40 %. Each lossy channel gets its crashes and its
window; one line per system, rate and channel.

Timings. SWIM: its defaults (ping 1 s, ping timeout 0.3 s, ping-req 0.9 s, suspect 5 s,
sync 0.5 s) give about 2 datagrams per member per second; all divided by 4 give about 8.
swarmd: the `udp()` preset (heartbeat 0.1 s) gives about 8; all its times multiplied by
4 (heartbeat 0.4 s) give about 2. The measured rates are printed next to the figures.

swim-protocol is not a dependency of swarmd: if `swimprotocol` 0.6.3 is not importable
here, the bench creates a venv under `$XDG_CACHE_HOME/swarmd-bench` (default
`~/.cache`) and pip-installs `swim-protocol==0.6.3` into it once; its members run with
that venv's Python (`bench/swim_member.py`).
"""

from __future__ import annotations

import argparse
import asyncio
import importlib.metadata
import json
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

if TYPE_CHECKING:
    from swarmd.core.params import Params

SWIM_VERSION = "0.6.3"
MEMBERS = 5
VICTIM = 2  # swarmd: robot 2 (an active); SWIM: the second member
HERE = Path(__file__).resolve().parent
CHANNELS = {"clean": (0.0, 0.0), "20% independent": (0.2, 0.0),
            "30% bursts of 8": (0.3, 8.0), "40% bursts of 4": (0.4, 4.0)}
"""Name -> (loss, mean burst in datagrams; 0: independent losses)."""
RATES = {"~2/s": 1.0, "~8/s": 4.0}
"""Label -> speed-up of SWIM's default timings; swarmd's udp() preset is slowed down by
4 / speed-up (heartbeat 0.4 s at ~2/s, 0.1 s at ~8/s)."""


# -- swim-protocol in its own venv ----------------------------------------------------------

def swim_python() -> str:
    """An interpreter that imports swimprotocol 0.6.3, installing it into a venv if need be."""
    try:
        if importlib.metadata.version("swim-protocol") == SWIM_VERSION:
            return sys.executable
    except importlib.metadata.PackageNotFoundError:
        pass
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    venv = cache / "swarmd-bench" / f"swim-{SWIM_VERSION}"
    python = venv / "bin" / "python"
    probe = [str(python), "-c", "import swimprotocol.udp"]
    if python.exists() and subprocess.run(probe, capture_output=True).returncode == 0:
        return str(python)
    print(f"installing swim-protocol=={SWIM_VERSION} into {venv} ...", file=sys.stderr)
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    subprocess.run([str(python), "-m", "pip", "install", "-q",
                    f"swim-protocol=={SWIM_VERSION}"], check=True)
    subprocess.run(probe, check=True)
    return str(python)


def free_port() -> int:
    """A port free for UDP and TCP on 127.0.0.1 (a SWIM member binds both)."""
    while True:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", 0))
            port: int = s.getsockname()[1]
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as t:
            try:
                t.bind(("127.0.0.1", port))
            except OSError:
                continue
        return port


@dataclass
class SwimMember:
    name: str
    proc: subprocess.Popen[str]
    statuses: list[tuple[float, str, str]] = field(default_factory=list)
    counters: list[tuple[float, int, int]] = field(default_factory=list)
    reader: threading.Thread | None = None

    def read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            try:
                rec = json.loads(line)
            except ValueError:
                continue
            if "status" in rec:
                self.statuses.append((rec["t"], rec["member"], rec["status"]))
            else:
                self.counters.append((rec["t"], rec["sent"], rec["bytes"]))

    def view(self) -> dict[str, str]:
        """member -> its latest status as this member sees it."""
        out: dict[str, str] = {}
        for _, member, status in list(self.statuses):
            out[member] = status
        return out

    def counter_at(self, t: float) -> tuple[int, int]:
        last = (0, 0)
        for ct, sent, nbytes in list(self.counters):
            if ct > t:
                break
            last = (sent, nbytes)
        return last


class SwimCluster:
    def __init__(self, python: str, scale: float, channel: tuple[float, float],
                 seed: int) -> None:
        names = [f"127.0.0.1:{free_port()}" for _ in range(MEMBERS)]
        self.members: list[SwimMember] = []
        loss, burst = channel
        for i, name in enumerate(names):
            cmd = [python, str(HERE / "swim_member.py"), "--name", name,
                   "--scale", str(scale), "--loss", str(loss), "--seed", str(seed * 100 + i),
                   "--burst-len", str(burst)]
            for peer in names:
                if peer != name:
                    cmd += ["--peer", peer]
            proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                    text=True, start_new_session=True)
            m = SwimMember(name, proc)
            m.reader = threading.Thread(target=m.read, daemon=True)
            m.reader.start()
            self.members.append(m)

    def converged(self) -> bool:
        for m in self.members:
            view = m.view()
            if any(view.get(o.name) != "ONLINE" for o in self.members if o is not m):
                return False
        return True

    def wait(self, cond: Any, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if cond():
                return True
            time.sleep(0.02)
        return bool(cond())

    def rates(self, start: float, end: float) -> tuple[float, float]:
        """Mean datagrams and bytes per member per second sent in [start, end]."""
        dgrams = nbytes = 0
        for m in self.members:
            s0, b0 = m.counter_at(start)
            s1, b1 = m.counter_at(end)
            dgrams, nbytes = dgrams + s1 - s0, nbytes + b1 - b0
        span = (end - start) * len(self.members)
        return dgrams / span, nbytes / span

    def stop(self) -> None:
        for m in self.members:
            if m.proc.poll() is None:
                m.proc.send_signal(signal.SIGTERM)
        for m in self.members:
            try:
                m.proc.wait(timeout=3)
            except subprocess.TimeoutExpired:
                m.proc.kill()
                m.proc.wait()


def steady(scale: float) -> float:
    """s to wait after the members first see each other: until then they still gossip
    the join (about 8 datagrams per member per second at the default timings, 2 after)."""
    return 12.0 / scale + 1.0


def swim_crash(python: str, scale: float, seed: int,
               channel: tuple[float, float] = (0.0, 0.0)) -> dict[str, Any]:
    cluster = SwimCluster(python, scale, channel, seed)
    try:
        if not cluster.wait(cluster.converged, 30):
            return {"error": "members never all saw each other ONLINE"}
        time.sleep(steady(scale))
        victim = cluster.members[VICTIM - 1]
        crash = time.time()
        dgrams, nbytes = cluster.rates(crash - 2.5, crash)
        os.killpg(victim.proc.pid, signal.SIGKILL)
        survivors = [m for m in cluster.members if m is not victim]

        def offline_marks() -> list[float]:
            return [t for m in survivors for t, name, st in list(m.statuses)
                    if name == victim.name and st == "OFFLINE" and t >= crash]

        cluster.wait(lambda: len(offline_marks()) >= len(survivors), 20.0 / scale + 10)
        marks = sorted(offline_marks())
        return {"detect": marks[0] - crash if marks else None,
                "all": marks[-1] - crash if len(marks) == len(survivors) else None,
                "dgrams": dgrams, "bytes": nbytes}
    finally:
        cluster.stop()


def swim_false(python: str, scale: float, window: float, seed: int,
               channel: tuple[float, float]) -> dict[str, Any]:
    cluster = SwimCluster(python, scale, channel, seed)
    try:
        cluster.wait(cluster.converged, 30)
        time.sleep(steady(scale))
        start = time.time()
        time.sleep(window)
        end = time.time()

        def count(status: str) -> int:
            return sum(1 for m in cluster.members for t, _, st in list(m.statuses)
                       if st == status and start <= t <= end)

        dgrams, nbytes = cluster.rates(start, end)
        return {"offline": count("OFFLINE"), "suspect": count("SUSPECT"),
                "dgrams": dgrams, "bytes": nbytes}
    finally:
        cluster.stop()


# -- swarmd --------------------------------------------------------------------------------

SLOWED = ("heartbeat_interval", "standby_heartbeat_interval", "t_max", "warn_interval",
          "vote_window", "claim_hold", "standby_timeout", "alert_after", "rejoin_hold")
"""The udp preset's timings the bench slows down; the start-up grace stays as it is."""


def slowed_params(slow_down: float) -> Params:
    """The udp preset with every `SLOWED` timing `slow_down` times longer."""
    from swarmd.core.params import udp

    base = udp()
    return base.with_overrides(**{n: round(getattr(base, n) * slow_down, 4) for n in SLOWED})


def swarm_file(directory: Path, slow_down: float) -> Path:
    """5 robots: 1-4 active in a ring (two watchers each, quorum 2), 5 standby for all."""
    params = slowed_params(slow_down)
    timing: dict[str, Any] = {"preset": "udp", **{n: getattr(params, n) for n in SLOWED}}
    doc = {
        "swarm": {"id": 4242, "name": "peers-bench"},
        "timing": timing,
        "functions": {f"f{i}": {"kind": "slot", "position": [float(i), 0.0, 1.0]}
                      for i in range(1, 5)},
        "robots": [
            {"id": 1, "state": "active", "function": "f1", "neighbors": [2, 4]},
            {"id": 2, "state": "active", "function": "f2", "neighbors": [1, 3]},
            {"id": 3, "state": "active", "function": "f3", "neighbors": [2, 4]},
            {"id": 4, "state": "active", "function": "f4", "neighbors": [1, 3]},
            {"id": 5, "state": "standby", "subs": [1, 2, 3, 4]},
        ],
    }
    path = directory / f"peers-{slow_down:g}.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


async def _swarmd_run(path: Path, *, duration: float, crash_at: float | None,
                      channel: tuple[float, float], seed: int,
                      ) -> tuple[dict[str, Any], list[tuple[float, int]], float]:
    from sim.realtime.orchestrator import run_realtime_async
    from sim.realtime.ports import PortLease
    from sim.realtime.summary import summarize_realtime
    from sim.shared.faults import parse_fault
    from swarmd.config import load_swarm
    from swarmd.transport.base import ChannelEvent
    from swarmd.transport.udp import UdpTransport

    cfg = load_swarm(path)
    # The run's multicast port, leased here rather than by the run, because the listener
    # must bind it before the robots start. The lease holds it until the run ended: a
    # port probed free and closed again could go to another run meanwhile, whose
    # datagrams the listener would count too (sim/realtime/ports.py).
    lease = PortLease()
    port = lease.port
    heard: list[tuple[float, int]] = []
    listener = UdpTransport(group="239.255.77.7", port=port, interface="127.0.0.1")

    def on_event(_event: ChannelEvent) -> None:
        pass

    faults = [parse_fault(f"crash:{VICTIM}@{crash_at}")] if crash_at is not None else []
    loss, burst = channel
    try:
        await listener.start(lambda data: heard.append((time.time(), len(data))), on_event)
        result = await run_realtime_async(
            path, duration=duration, faults=faults, loss=loss, seed=seed, port=port,
            loss_model="burst" if burst else "bernoulli", burst_len=burst or 4.0)
    finally:
        await listener.close()
        lease.release()
    summary = summarize_realtime(result, faults, cfg.to_plan(), cfg.params(), loss=loss)
    return summary.as_dict(), heard, result.t0


def _rate(heard: list[tuple[float, int]], start: float, end: float) -> tuple[float, float]:
    inside = [n for t, n in heard if start <= t <= end]
    span = (end - start) * MEMBERS
    return len(inside) / span, sum(inside) / span


def swarmd_crash(path: Path, slow_down: float, seed: int,
                 channel: tuple[float, float] = (0.0, 0.0)) -> dict[str, Any]:
    params = slowed_params(slow_down)
    lossy = bool(channel[0])
    # After the processes' start (a second), the start-up grace and two t_max of calm;
    # on a lossy channel half a minute more, in which the watchers measure the links
    # (DESIGN "Detection").
    crash_at = 1.0 + params.startup_grace + 2 * params.t_max + (30.0 if lossy else 0.0)
    # The takeover, with two seconds to spare.
    settle = 2.0 + params.takeover_bound(lossy=lossy)
    doc, heard, t0 = asyncio.run(_swarmd_run(path, duration=crash_at + settle,
                                             crash_at=crash_at, channel=channel, seed=seed))
    fault = doc["faults"][0] if doc["faults"] else {}
    dgrams, nbytes = _rate(heard, t0 + crash_at - 2.5, t0 + crash_at)
    return {"detect": fault.get("detection_latency"), "takeover": fault.get("takeover_latency"),
            "dgrams": dgrams, "bytes": nbytes, "problems": doc.get("process_problems")}


def swarmd_false(path: Path, window: float, seed: int,
                 channel: tuple[float, float]) -> dict[str, Any]:
    doc, heard, t0 = asyncio.run(_swarmd_run(path, duration=window, crash_at=None,
                                             channel=channel, seed=seed))
    dgrams, nbytes = _rate(heard, t0 + 3.0, t0 + window)
    return {"takeovers": doc["false_takeovers"], "suspicions": doc["false_suspicions"],
            "dgrams": dgrams, "bytes": nbytes}


# -- the table -----------------------------------------------------------------------------

def p99(xs: list[float]) -> float:
    """Nearest-rank 99th percentile (the maximum for fewer than 100 samples)."""
    ordered = sorted(xs)
    return ordered[max(0, -(-99 * len(ordered) // 100) - 1)]


def vals(rs: list[dict[str, Any]], key: str) -> list[float]:
    return [r[key] for r in rs if r.get(key) is not None]


def mean(rs: list[dict[str, Any]], key: str, digits: int) -> str:
    xs = vals(rs, key)
    return f"{statistics.mean(xs):.{digits}f}" if xs else "-"


def fmt(xs: list[float]) -> str:
    if not xs:
        return "-"
    return f"{statistics.median(xs):.2f} / {p99(xs):.2f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true",
                    help="3 crashes per system, rate and channel; 30 s windows")
    ap.add_argument("--runs", type=int, default=None, help="crashes per system and rate")
    ap.add_argument("--window", type=float, default=None,
                    help="seconds with no crash on each lossy channel")
    ap.add_argument("--channel", action="append", choices=sorted(CHANNELS), default=None,
                    help="only these channels (repeatable; default: every one)")
    ap.add_argument("--json", type=Path, default=None, help="also write the raw figures here")
    args = ap.parse_args()
    runs = args.runs or (3 if args.quick else 10)
    window = args.window or (30.0 if args.quick else 120.0)
    channels = {name: CHANNELS[name] for name in args.channel or CHANNELS}
    python = swim_python()
    raw: dict[str, Any] = {"swim_protocol": SWIM_VERSION, "runs": runs, "window_s": window}
    rows = []
    with tempfile.TemporaryDirectory(prefix="swarmd-peers-") as tmp:
        for label, scale in RATES.items():
            slow_down = 4.0 / scale
            path = swarm_file(Path(tmp), slow_down)
            for name, channel in channels.items():
                got = one_channel(python, path, scale, slow_down, channel, runs, window)
                raw[f"{label}, {name}"] = got
                rows += table_rows(got, label, name, scale, slow_down)
    header = ("system", "rate", "channel", "datagrams/member/s", "bytes/member/s",
              "crash->takeover s (median / p99)", "crash->detection s (median / p99)",
              f"false, {window:g} s with no crash")
    print(f"5 members on loopback, {runs} crashes per row (kill -9 of one member)\n")
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for row in rows:
        print("| " + " | ".join(row) + " |")
    if args.json is not None:
        args.json.write_text(json.dumps(raw, indent=2))


def one_channel(python: str, path: Path, scale: float, slow_down: float,
                channel: tuple[float, float], runs: int, window: float) -> dict[str, Any]:
    """Both systems' crashes on one channel and, if it is lossy, their false detections."""
    got: dict[str, Any] = {
        "swim": [swim_crash(python, scale, seed, channel) for seed in range(runs)],
        "swarmd": [swarmd_crash(path, slow_down, seed, channel) for seed in range(runs)],
    }
    if channel[0]:
        got["swim_loss"] = swim_false(python, scale, window, 1, channel)
        got["swarmd_loss"] = swarmd_false(path, window, 1, channel)
    return got


def table_rows(got: dict[str, Any], label: str, name: str, scale: float,
               slow_down: float) -> list[tuple[str, ...]]:
    swim, ours = got["swim"], got["swarmd"]
    swim_loss, ours_loss = got.get("swim_loss"), got.get("swarmd_loss")
    missed_swim = sum(1 for r in swim if r.get("detect") is None)
    missed_ours = sum(1 for r in ours if r.get("takeover") is None)
    return [(
        f"swim-protocol {SWIM_VERSION} (defaults / {scale:g})", label, name,
        mean(swim, "dgrams", 1), mean(swim, "bytes", 0), "-",
        fmt(vals(swim, "detect")) + (f" ({missed_swim} missed)" if missed_swim else ""),
        f"{swim_loss['offline']} OFFLINE ({swim_loss['suspect']} SUSPECT)"
        if swim_loss else "-",
    ), (
        f"swarmd (heartbeat {slowed_params(slow_down).heartbeat_interval:g} s)", label, name,
        mean(ours, "dgrams", 1), mean(ours, "bytes", 0),
        fmt(vals(ours, "takeover")) + (f" ({missed_ours} missed)" if missed_ours else ""),
        fmt(vals(ours, "detect")),
        f"{ours_loss['takeovers']} takeovers ({ours_loss['suspicions']} suspicions)"
        if ours_loss else "-",
    )]


if __name__ == "__main__":
    main()
