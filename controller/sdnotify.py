"""systemd's notify protocol (sd_notify) without a library: READY, the watchdog ping, STOPPING.

Under ``Type=notify`` with ``WatchdogSec=``, systemd passes ``NOTIFY_SOCKET`` and ``WATCHDOG_USEC``;
the controller pings from inside its tick (docs/FAULTS.md F21: a hung loop must stop the pings, which a
helper thread would not), at most every half watchdog period. Outside systemd every call is a
no-op.
"""

from __future__ import annotations

import os
import socket


class Notifier:
    def __init__(self, environ: dict[str, str] | None = None) -> None:
        env = os.environ if environ is None else environ
        address = env.get("NOTIFY_SOCKET")
        self._sock: socket.socket | None = None
        self._address: str | bytes | None = None
        if address:
            self._address = "\0" + address[1:] if address.startswith("@") else address
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        usec = env.get("WATCHDOG_USEC", "")
        self.watchdog_interval_ns = int(usec) * 1000 // 2 if usec.isdigit() and int(usec) > 0 else None
        self._last_ping_ns: int | None = None
        self.failures = 0

    @property
    def active(self) -> bool:
        return self._sock is not None

    def _send(self, text: str) -> None:
        if self._sock is None:
            return
        try:
            self._sock.sendto(text.encode(), self._address)
        except OSError:
            self.failures += 1  # systemd went away: nothing the loop can do about it

    def ready(self, status: str = "") -> None:
        self._send("READY=1" + (f"\nSTATUS={status}" if status else ""))

    def ping(self, now_ns: int) -> None:
        """Call every tick; sends WATCHDOG=1 when half the watchdog period has passed."""
        if self.watchdog_interval_ns is None:
            return
        if self._last_ping_ns is None or now_ns - self._last_ping_ns >= self.watchdog_interval_ns:
            self._send("WATCHDOG=1")
            self._last_ping_ns = now_ns

    def stopping(self) -> None:
        self._send("STOPPING=1")

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None
