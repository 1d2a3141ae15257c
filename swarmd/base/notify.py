"""systemd's service notification protocol (sd_notify), spoken directly.

The protocol is one datagram of newline-separated ``KEY=VALUE`` lines sent to the
``AF_UNIX`` socket named by ``$NOTIFY_SOCKET`` (a path, or an abstract socket when it
starts with ``@``); see sd_notify(3), section "Notes", which documents it as a stable
interface that may be reimplemented. It is small enough that a library would add a
dependency for twenty lines.

How the daemon uses it (deploy/swarmd.service ``Type=notify``):

- ``READY=1`` once the transport is up and the first heartbeat is out, so
  ``systemctl start`` returns only when the robot is really on the channel;
- ``STATUS=...`` with role and function, shown by ``systemctl status swarmd``;
- ``WATCHDOG=1`` from the event loop every `watchdog_period()` seconds (half of
  ``WatchdogSec``), so a hung loop stops pinging and systemd restarts the daemon;
- ``STOPPING=1`` when shutdown begins.

Without ``$NOTIFY_SOCKET`` (run by hand, in tests, in ``sim``) every call is a no-op. A
send failure never raises: the daemon's job is the swarm, not its supervisor, so a
failure is counted, logged once, and the daemon goes on (common rule: bad input never
takes the daemon down).
"""

from __future__ import annotations

import logging
import os
import socket
from collections.abc import Mapping

# The name an operator filters the JSON logs on ("logger", docs/daemon.md): it names the
# component, not the file, so it stays when the module moves between folders.
log = logging.getLogger("swarmd.notify")


class Notifier:
    """Sends sd_notify datagrams to one socket address, or does nothing.

    Build it with `from_env()`; the constructor is for tests and for callers that
    already know the address.
    """

    def __init__(self, address: str | None, watchdog_usec: int | None = None) -> None:
        self._address = _socket_address(address) if address else None
        self._watchdog_usec = watchdog_usec if watchdog_usec and watchdog_usec > 0 else None
        self._sock: socket.socket | None = None
        self.sent = 0
        """Datagrams delivered to the socket."""
        self.failures = 0
        """Datagrams that could not be sent (logged once, then only counted)."""

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None) -> Notifier:
        """Read ``NOTIFY_SOCKET``, ``WATCHDOG_USEC`` and ``WATCHDOG_PID``.

        ``WATCHDOG_PID`` names the process systemd expects pings from; when it is set
        and is not this process (a child that inherited the environment), the watchdog
        is off for us, as sd_watchdog_enabled(3) specifies.
        """
        env = os.environ if environ is None else environ
        address = env.get("NOTIFY_SOCKET") or None
        usec: int | None = None
        raw_usec = env.get("WATCHDOG_USEC", "")
        raw_pid = env.get("WATCHDOG_PID", "")
        try:
            usec = int(raw_usec) if raw_usec else None
        except ValueError:
            log.warning("ignoring WATCHDOG_USEC=%r: not an integer", raw_usec)
        if usec is not None and raw_pid:
            try:
                if int(raw_pid) != os.getpid():
                    usec = None
            except ValueError:
                log.warning("ignoring WATCHDOG_PID=%r: not an integer", raw_pid)
                usec = None
        return cls(address, usec)

    @property
    def enabled(self) -> bool:
        """True when there is a socket to notify."""
        return self._address is not None

    def watchdog_period(self) -> float | None:
        """Seconds between `watchdog()` calls: half of ``WatchdogSec`` (the margin
        systemd.service(5) recommends), or None when no watchdog is configured."""
        if self._address is None or self._watchdog_usec is None:
            return None
        return self._watchdog_usec / 2_000_000

    def ready(self, status: str | None = None) -> bool:
        """Start-up is complete (transport up, first heartbeat sent)."""
        return self.notify({"READY": "1", **({"STATUS": status} if status else {})})

    def status(self, text: str) -> bool:
        """One line for ``systemctl status``, e.g. ``ACTIVE f2 epoch 3``."""
        return self.notify({"STATUS": text})

    def watchdog(self) -> bool:
        """Keep-alive ping: the event loop is still turning."""
        return self.notify({"WATCHDOG": "1"})

    def stopping(self, status: str | None = None) -> bool:
        """Shutdown has begun."""
        return self.notify({"STOPPING": "1", **({"STATUS": status} if status else {})})

    def notify(self, fields: Mapping[str, str]) -> bool:
        """Send one datagram; True when it went out. Never raises."""
        if self._address is None:
            return False
        lines = []
        for key, value in fields.items():
            # A newline would start a new assignment: systemd would read a forged key.
            lines.append(f"{key}={value.replace(chr(10), ' ')}")
        payload = ("\n".join(lines) + "\n").encode("utf-8", "replace")
        try:
            if self._sock is None:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
                self._sock.setblocking(False)
            self._sock.sendto(payload, self._address)
        except OSError as exc:
            self.failures += 1
            if self.failures == 1:
                log.warning("sd_notify to %r failed (%s); further failures only counted",
                            self._address, exc)
            return False
        self.sent += 1
        return True

    def close(self) -> None:
        """Release the socket (later calls reopen it)."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None


def _socket_address(value: str) -> str | bytes:
    # sd_notify(3): "@" at the start means the Linux abstract namespace (a leading NUL).
    if value.startswith("@"):
        return b"\0" + value[1:].encode()
    return value
