"""The systemd notify protocol: READY, watchdog pings at half the period, a no-op outside systemd."""

from __future__ import annotations

import socket

from controller.sdnotify import Notifier


def test_outside_systemd_everything_is_a_no_op():
    n = Notifier({})
    assert not n.active and n.watchdog_interval_ns is None
    n.ready()
    n.ping(0)
    n.stopping()


def test_ready_and_pings_reach_the_socket(tmp_path):
    path = str(tmp_path / "notify")
    server = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    server.bind(path)
    server.settimeout(5)
    try:
        n = Notifier({"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "200000"})  # 200 ms: ping every 100 ms
        n.ready("holding")
        assert server.recv(100) == b"READY=1\nSTATUS=holding"
        for t_ms in range(0, 300, 20):  # ticks every 20 ms
            n.ping(t_ms * 1_000_000)
        pings = []
        server.settimeout(0.2)
        try:
            while True:
                pings.append(server.recv(100))
        except socket.timeout:
            pass
        assert pings == [b"WATCHDOG=1"] * 3  # at 0, 100 and 200 ms
        n.stopping()
        server.settimeout(5)
        assert server.recv(100) == b"STOPPING=1"
        n.close()
    finally:
        server.close()
