"""`swarmd start` under cProfile, measuring CPU time from READY until the daemon is
told to stop (start-up imports and the shutdown are left out), for
`bench_daemon.py --profile`.

    python bench/profile_daemon.py STATS_FILE start --config robot.yaml
"""

from __future__ import annotations

import cProfile
import sys
import time
from typing import Any


def main() -> None:
    out = sys.argv.pop(1)
    profile = cProfile.Profile(time.process_time)
    from swarmd.base import notify

    ready, stopping = notify.Notifier.ready, notify.Notifier.stopping

    def ready_then_profile(self: Any, *args: Any, **kwargs: Any) -> bool:
        done: bool = ready(self, *args, **kwargs)
        profile.enable()
        return done

    def stop_profiling(self: Any, *args: Any, **kwargs: Any) -> bool:
        profile.disable()
        profile.dump_stats(out)
        done: bool = stopping(self, *args, **kwargs)
        return done

    notify.Notifier.ready = ready_then_profile  # type: ignore[method-assign]
    notify.Notifier.stopping = stop_profiling  # type: ignore[method-assign]
    from swarmd.cli import main as cli

    sys.argv[0] = "swarmd"
    cli()


if __name__ == "__main__":
    main()
