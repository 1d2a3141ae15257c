"""CPU and memory of one idle daemon at 10 Hz heartbeats (goal < 1% of a core,
< 60 MB RSS).

Runs the paper swarm as real `swarmd start` processes on loopback multicast (random
port) and measures robot 1 (udp() timing: ACTIVE, heartbeating at 10 Hz, hearing its
neighbours' 10 Hz heartbeats and the standbys' 2 Hz ones) from /proc for `--duration`
seconds after READY. `--alone` runs robot 1 without its swarm: it then also warns about
its silent neighbours at 10 Hz (a busier case than idle). `--auth` picks how the swarm
signs: `per-robot` (the default, as configs/paper.yaml: keys made for the run), `shared`
or `none`. `--failover` kills robot 2 (SIGKILL) as the measurement starts and measures
robot 1 (a watcher of f2: it suspects, warns, sees the takeover) and robot 6 (the standby
that claims and takes f2 over) through the failover and after it.

`--compare REV` keeps a gain measurable: it checks REV out into a temporary `git
worktree` and measures it and this tree alternately (`--runs` times each, in one run, so
both see the same machine load), then prints the median of each tree and their ratio
(this tree / REV) for robot 1's CPU, the standby's and RSS, with the load average. Each
tree's own code makes its keys and runs its daemons (`--tree PATH` measures another
checkout). `--together` runs both trees' swarms at the same time instead, each on its own
port, and measures them over the same seconds: on a machine shared with other jobs a load
that comes and goes then weighs on both trees alike. `--profile FILE` runs robot 1
(`--profile-robot 6`: the standby) under cProfile, CPU time, from READY until it is
told to stop, writes the stats to FILE and prints the top entries per frame.
`--floor` also measures, beside robot 1 and the standby, a bare process for each on the
daemon's event loop (bench/bare_listener.py) that wakes for every frame on the group and
at that robot's heartbeat period, sends its heartbeats and does the checks `--auth` makes
unavoidable for the frames it hears (Ed25519 anchors and chain links; the swarm key's
tag), and nothing else: the part of their CPU that no change to swarmd's code removes
without changing the frames on the wire, at the machine's current load. With
`--compare` it prints each floor over REV's robot: above 0.5, halving REV's CPU is out
of reach there.

    python bench/bench_daemon.py [--duration 10] [--alone | --failover]
                                 [--auth per-robot|shared|none]
                                 [--compare REV [--runs 3] [--together]]
                                 [--profile FILE [--profile-robot 1|6]] [--floor]
"""

from __future__ import annotations

import argparse
import importlib
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
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
PROFILER = Path(__file__).resolve().parent / "profile_daemon.py"
BARE = Path(__file__).resolve().parent / "bare_listener.py"

AUTH = {"per-robot": "auth: {mode: per-robot, keys_dir: keys}",
        "shared": "auth: {mode: shared, key_file: swarm.key}", "none": "auth: none"}


def swarm_file(root: Path, tmp: Path, auth: str) -> Path:
    """`root`'s configs/paper.yaml in `tmp`, signed as `auth` says, with its keys made
    there by `root`'s own code (a tree compared with another makes keys its way)."""
    text = (root / "configs" / "paper.yaml").read_text()
    lines = [AUTH[auth] if line.startswith("auth:") else line for line in text.splitlines()]
    if auth == "per-robot":
        identity: Any = importlib.import_module("swarmd.base.identity")
        for robot in range(1, 7):
            identity.write_identity(tmp / "keys", robot)
    elif auth == "shared":
        importlib.import_module("swarmd.base.keys").generate_key(tmp / "swarm.key")
    path = tmp / "paper.yaml"
    path.write_text("\n".join(lines) + "\n")
    return path


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    utime, stime = int(fields[11]), int(fields[12])  # fields 14 and 15 of proc(5)
    return (utime + stime) / os.sysconf("SC_CLK_TCK")


def cpu_exact(pid: int) -> float:
    """Seconds on a CPU of every thread `pid` has now, from the scheduler
    (/proc/PID/task/*/schedstat, nanoseconds): not rounded to the clock tick, which is
    0.05 % of a 20 s run, as `cpu_seconds` is. A thread that ended meanwhile takes its
    time with it; a daemon's threads live as long as it does."""
    total = 0
    for stat in Path(f"/proc/{pid}/task").glob("*/schedstat"):
        try:
            total += int(stat.read_text().split()[0])
        except (OSError, ValueError, IndexError):
            continue  # a thread that ended as it was read
    return total / 1e9


def status_kb(pid: int, key: str) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return int(line.split()[1])
    raise KeyError(key)


def lease_port() -> socket.socket:
    """A socket on a UDP port of 127.0.0.1 the kernel picked, bound without reuse
    options: while it is open, no other bind of 127.0.0.1 gets that port, and the
    daemons, which bind the multicast group's address on it, are not in its way. A port
    probed free and closed again could go to another swarm (another bench, a test) before
    or while these daemons bound it, and the two would hear each other. The socket of
    sim/realtime/ports.py's PortLease, written out here because the bench may measure a
    tree from before that module (`--compare`, `--tree`), whose code it imports."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind(("127.0.0.1", 0))
    except BaseException:
        sock.close()
        raise
    return sock


def measure(args: argparse.Namespace, root: Path) -> dict[str, Any] | None:
    """Run the swarm of `root` (robot 1 alone with `--alone`) and measure robot 1 and
    the standby (robot 6) for `args.duration` s after READY; None if robot 1 never
    became ready."""
    env = {k: v for k, v in os.environ.items() if k != "NOTIFY_SOCKET"}
    env["PYTHONPATH"] = str(root)
    with lease_port() as lease, tempfile.TemporaryDirectory() as tmp:
        port: int = lease.getsockname()[1]
        swarm = swarm_file(root, Path(tmp), args.auth)
        private_key_path: Any = importlib.import_module("swarmd.base.identity").private_key_path

        def launch(robot: int) -> subprocess.Popen[str]:
            cfg = Path(tmp) / f"robot{robot}.yaml"
            identity = (f"identity_file: {private_key_path(Path(tmp) / 'keys', robot)}\n"
                        if args.auth == "per-robot" else "")
            cfg.write_text(f"robot: {robot}\nswarm: {swarm}\n"
                           f"transport: {{kind: udp, port: {port}}}\n"
                           f"state_dir: {tmp}/state{robot}\n" + identity)
            how = [str(PROFILER), args.profile] \
                if robot == args.profile_robot and args.profile \
                else ["-m", "swarmd.cli"]
            return subprocess.Popen([sys.executable, *how, "start", "--config", str(cfg)],
                                    stdout=subprocess.PIPE, text=True, env=env, cwd=root)

        others = [] if args.alone else [launch(r) for r in (2, 3, 4, 5, 6)]
        proc = launch(1)
        floors = [floor(args, port, Path(tmp), swarm, r)
                  for r in ((1,) if args.alone else (1, 6))] if args.floor else []
        try:
            return _measure_running(args, proc, others, floors)
        finally:
            for p in (proc, *others, *floors):
                p.send_signal(signal.SIGTERM)
            for p in (proc, *others, *floors):
                try:
                    p.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    p.kill()


def floor(args: argparse.Namespace, port: int, tmp: Path, swarm: Path,
          robot: int) -> subprocess.Popen[str]:
    """The floor of `robot` (bench/bare_listener.py), always this tree's code: waking
    for the same frames, and that robot's checks and sends in `args.auth`."""
    group = importlib.import_module("swarmd.transport.addresses").DEFAULT_GROUP
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen([sys.executable, str(BARE), group, str(port), "--as", str(robot),
                             "--swarm", str(swarm), "--auth", args.auth,
                             "--keys", str(tmp / "keys"), "--key", str(tmp / "swarm.key")],
                            stdout=subprocess.PIPE, text=True, env=env)


def _measure_running(args: argparse.Namespace, proc: subprocess.Popen[str],
                     others: list[subprocess.Popen[str]],
                     floors: list[subprocess.Popen[str]]) -> dict[str, Any] | None:
    """Wait for robot 1's READY, then measure it (and robot 6, the standby, and with
    `--floor` the floors of both)."""
    assert proc.stdout is not None
    standby = others[-1] if others else None
    for started in floors:
        if started.stdout is None or started.stdout.readline() != "ready\n":
            raise SystemExit("bench/bare_listener.py did not start")
    bare = floors[0] if floors else None
    standby_bare = floors[1] if len(floors) > 1 else None
    for line in proc.stdout:
        if json.loads(line)["msg"] == "ready":
            break
    else:
        return None
    # Keep reading stdout so no pipe ever fills (the daemons log their events).
    for p in (proc, *others):
        out = p.stdout
        assert out is not None
        threading.Thread(target=out.read, daemon=True).start()
    if args.hold:  # `--together`: the parent starts every tree's measurement at once
        print("ready", flush=True)
        sys.stdin.readline()
    measured = [p for p in (proc, standby, bare, standby_bare) if p is not None]
    t0, ticks0 = time.monotonic(), {p.pid: cpu_seconds(p.pid) for p in measured}
    exact0 = {p.pid: cpu_exact(p.pid) for p in measured}
    if args.failover:
        others[0].kill()  # robot 2: a crash, nothing said
    time.sleep(args.duration)
    t1, ticks1 = time.monotonic(), {p.pid: cpu_seconds(p.pid) for p in measured}
    exact1 = {p.pid: cpu_exact(p.pid) for p in measured}

    def share(p: subprocess.Popen[str] | None, at0: dict[int, float],
              at1: dict[int, float]) -> float:
        return 0.0 if p is None else round(100.0 * (at1[p.pid] - at0[p.pid]) / (t1 - t0), 3)

    return {"cpu_percent": share(proc, ticks0, ticks1),
            "standby_cpu_percent": share(standby, ticks0, ticks1),
            "cpu_exact_percent": share(proc, exact0, exact1),
            "standby_cpu_exact_percent": share(standby, exact0, exact1),
            **({"floor_cpu_percent": share(bare, exact0, exact1),
                "standby_floor_cpu_percent": share(standby_bare, exact0, exact1)}
               if bare is not None else {}),
            "rss_mb": round(status_kb(proc.pid, "VmRSS") / 1024, 1),
            "peak_rss_mb": round(status_kb(proc.pid, "VmHWM") / 1024, 1),
            "seconds": round(t1 - t0, 2), "auth": args.auth}


def report(args: argparse.Namespace, r: dict[str, Any]) -> int:
    """Print one measurement; the exit code says whether it met the goals."""
    what = ("alone (warning at 10 Hz)" if args.alone else "in the paper swarm") + \
        (", robot 2 crashing as the measurement starts" if args.failover else "") + \
        f", auth {args.auth}"
    print(f"daemon of robot 1 {what}, 10 Hz heartbeats, {r['seconds']:.1f} s: "
          f"CPU {r['cpu_percent']:.2f}% of one core (goal < 1%), RSS {r['rss_mb']:.1f} MB, "
          f"peak RSS {r['peak_rss_mb']:.1f} MB (goal < 60 MB)")
    if args.failover:
        print(f"daemon of robot 6, the standby taking f2 over: CPU "
              f"{r['standby_cpu_percent']:.2f}% of one core")
    if "floor_cpu_percent" in r:
        print(f"the floor (bench/bare_listener.py: waking for the same frames, their "
              f"checks in auth {args.auth}): robot 1 {r['floor_cpu_percent']:.3f}%, "
              f"standby {r['standby_floor_cpu_percent']:.3f}% of one core")
    print(json.dumps(r))
    return 0 if r["cpu_percent"] < 1.0 and r["peak_rss_mb"] < 60 else 2


def child_args(args: argparse.Namespace, tree: Path) -> list[str]:
    """This script's command line measuring `tree` once, as `args` asks."""
    cmd = [sys.executable, str(Path(__file__).resolve()), "--tree", str(tree),
           "--duration", str(args.duration), "--auth", args.auth]
    return cmd + ["--alone"] * args.alone + ["--failover"] * args.failover + \
        ["--floor"] * args.floor


def compare(args: argparse.Namespace) -> int:
    """`--compare REV`: REV and this tree alternately, `args.runs` times each."""
    with tempfile.TemporaryDirectory(prefix="bench-daemon-") as tmp:
        other = Path(tmp) / "rev"
        made = subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach",
                               "--quiet", str(other), args.compare],
                              capture_output=True, text=True)
        if made.returncode != 0:
            raise SystemExit(f"cannot check out {args.compare!r} beside this tree: "
                             f"{made.stderr.strip()}")
        try:
            trees = {args.compare: other, "this tree": ROOT}
            results = _together(args, trees) if args.together else _alternate(args, trees)
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force",
                            str(other)], check=False)
    return _print_comparison(args, results)


def _alternate(args: argparse.Namespace,
               trees: dict[str, Path]) -> dict[str, list[dict[str, Any]]]:
    """Each tree measured `args.runs` times, taking turns."""
    results: dict[str, list[dict[str, Any]]] = {name: [] for name in trees}
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}",
          flush=True)
    for i in range(args.runs):
        for name, tree in trees.items():
            out = subprocess.run(child_args(args, tree), capture_output=True, text=True)
            results[name].append(_measured(args, i, name, out.stdout, out.stderr))
    return results


def _measured(args: argparse.Namespace, i: int, name: str, out: str,
              err: str = "") -> dict[str, Any]:
    """Run `i` of tree `name`: the figures its child printed last, echoed in one line."""
    lines = out.strip().splitlines()
    if not lines or not lines[-1].startswith("{"):
        raise SystemExit(f"{name}: measurement failed:\n{out}{err}")
    r: dict[str, Any] = json.loads(lines[-1])
    floor = (f", floors {r['floor_cpu_percent']:.3f}% / "
             f"{r['standby_floor_cpu_percent']:.3f}%") if args.floor else ""
    print(f"run {i + 1} {name:>10}: robot 1 {r['cpu_percent']:.2f}% "
          f"(exact {r['cpu_exact_percent']:.3f}%), standby {r['standby_cpu_percent']:.2f}% "
          f"(exact {r['standby_cpu_exact_percent']:.3f}%){floor}, RSS {r['rss_mb']:.1f} MB, "
          f"load {os.getloadavg()[0]:.2f}", flush=True)
    return r


def _together(args: argparse.Namespace,
              trees: dict[str, Path]) -> dict[str, list[dict[str, Any]]]:
    """Each tree's swarm running at the same time, on its own port, `args.runs` times:
    both measured over the same seconds, so a load that comes and goes on a shared
    machine weighs on both alike (taking turns, it falls on one run of one tree)."""
    results: dict[str, list[dict[str, Any]]] = {name: [] for name in trees}
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}",
          flush=True)
    for i in range(args.runs):
        procs = {name: subprocess.Popen([*child_args(args, tree), "--hold"],
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                        text=True) for name, tree in trees.items()}
        for name, p in procs.items():  # every swarm up before any measurement starts
            assert p.stdout is not None
            if p.stdout.readline() != "ready\n":
                raise SystemExit(f"{name}: its swarm did not start")
        for p in procs.values():
            assert p.stdin is not None
            p.stdin.write("go\n")
            p.stdin.flush()
        for name, p in procs.items():
            out, _ = p.communicate()
            results[name].append(_measured(args, i, name, out))
    return results


def _print_comparison(args: argparse.Namespace,
                      results: dict[str, list[dict[str, Any]]]) -> int:
    (rev, old), (_, new) = results.items()
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    summary: dict[str, Any] = {"compare": rev, "runs": args.runs, "auth": args.auth,
                               "duration": args.duration}
    keys = [("cpu_percent", "robot 1 CPU %"), ("standby_cpu_percent", "standby CPU %"),
            ("cpu_exact_percent", "robot 1 exact %"),
            ("standby_cpu_exact_percent", "standby exact %"),
            ("rss_mb", "RSS MB")]
    if args.floor:
        # What swarmd's own code costs: each run's robot 1 less the floor beside it.
        for r in (*old, *new):
            r["above_floor_percent"] = round(r["cpu_exact_percent"] - r["floor_cpu_percent"],
                                             3)
        keys += [("floor_cpu_percent", "floor CPU %"),
                 ("standby_floor_cpu_percent", "standby floor %"),
                 ("above_floor_percent", "robot 1 - floor")]
    for key, label in keys:
        a = statistics.median(r[key] for r in old)
        b = statistics.median(r[key] for r in new)
        ratio = b / a if a else float("nan")
        print(f"{label:>15}: {rev} median {a:.3f}, this tree median {b:.3f}, "
              f"ratio {ratio:.2f}")
        summary[key] = {"rev": a, "this": b, "ratio": round(ratio, 3)}
    if args.floor:
        summary["floor_vs_rev"] = _floor_vs_rev(rev, old, new)
    print(json.dumps(summary))
    return 0


def _floor_vs_rev(rev: str, old: list[dict[str, Any]],
                  new: list[dict[str, Any]]) -> dict[str, float]:
    """Each floor of this tree (beside this tree's swarm: the frames it puts on the wire,
    which REV's may not match) over REV's own robot: above 0.5, halving REV's CPU is out
    of reach without changing those frames."""
    ratios: dict[str, float] = {}
    for floor_key, key, label in (("floor_cpu_percent", "cpu_exact_percent", "robot 1"),
                                  ("standby_floor_cpu_percent", "standby_cpu_exact_percent",
                                   "standby")):
        floor_median = statistics.median(r[floor_key] for r in new)
        rev_median = statistics.median(r[key] for r in old)
        ratio = round(floor_median / rev_median, 3) if rev_median else float("nan")
        verdict = ("the floor leaves room for half" if ratio <= 0.5
                   else "half is out of reach with these frames")
        print(f"{label + ' floor':>15}: median {floor_median:.3f}%, {rev}'s {label} "
              f"{rev_median:.3f}%: ratio {ratio:.2f} ({verdict})")
        ratios[label] = ratio
    return ratios


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=10.0, help="seconds measured")
    ap.add_argument("--alone", action="store_true", help="robot 1 without its swarm")
    ap.add_argument("--failover", action="store_true",
                    help="kill robot 2 as the measurement starts; measure robots 1 and 6")
    ap.add_argument("--auth", choices=sorted(AUTH), default="per-robot",
                    help="how the swarm signs (default per-robot)")
    ap.add_argument("--compare", metavar="REV",
                    help="measure git revision REV and this tree alternately; print the "
                         "ratio of medians")
    ap.add_argument("--runs", type=int, default=3,
                    help="measurements of each tree with --compare (default 3)")
    ap.add_argument("--together", action="store_true",
                    help="with --compare: run both trees' swarms at the same time (each on "
                         "its own port) instead of in turns")
    ap.add_argument("--hold", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--tree", type=Path, default=ROOT,
                    help="the checkout whose daemons are measured (default this one)")
    ap.add_argument("--floor", action="store_true",
                    help="also measure the floor of robot 1 and of the standby "
                         "(bench/bare_listener.py): waking for the same frames and their "
                         "unavoidable checks, at this load")
    ap.add_argument("--profile", metavar="FILE",
                    help="run a robot (--profile-robot, default 1) under cProfile (CPU time, "
                         "READY to stop); stats to FILE")
    ap.add_argument("--profile-robot", type=int, choices=(1, 6), default=1,
                    help="the robot --profile runs: 1 (active) or 6 (the standby)")
    args = ap.parse_args()
    if args.compare:
        if args.runs < 1:
            ap.error("--runs must be at least 1")
        return compare(args)
    root = args.tree.resolve()
    sys.path.insert(0, str(root))
    r = measure(args, root)
    if r is None:
        print("daemon exited before READY", file=sys.stderr)
        return 1
    code = report(args, r)
    if args.profile:
        print_profile(args.profile, args.profile_robot)
    return code


def print_profile(path: str, robot: int, top: int = 25) -> None:
    """The top entries of `robot`'s profile, in microseconds per frame (in and out)."""
    import pstats

    stats = pstats.Stats(path)
    raw: Any = stats.stats  # type: ignore[attr-defined]
    # Frames in: the runtime's receive callback; out: the transport's send (both trees).
    calls = {(Path(func[0]).name, func[2]): value[1] for func, value in raw.items()}
    n_in, n_out = calls.get(("runtime.py", "_on_frame"), 0), calls.get(("udp.py", "send"), 0)
    frames = n_in + n_out
    total: float = stats.total_tt  # type: ignore[attr-defined]
    print(f"profile of robot {robot}: {n_in} frames in, {n_out} out, {total:.3f} s CPU under "
          f"the profiler ({1e6 * total / max(1, frames):.0f} us per frame)")
    rows = sorted(raw.items(), key=lambda kv: kv[1][3], reverse=True)[:top]
    print(f"{'cumulative us/frame':>20} {'own us/frame':>13} {'calls':>7}  function")
    for (file, line, name), (_, ncalls, tt, ct, _) in rows:
        where = f"{Path(file).name}:{line}({name})" if line else name
        print(f"{1e6 * ct / max(1, frames):>20.1f} {1e6 * tt / max(1, frames):>13.1f} "
              f"{ncalls:>7}  {where}")


if __name__ == "__main__":
    sys.exit(main())
