"""Shared test set-up: Hypothesis profiles, the vcan0 and UDP multicast gates, and a check that no test leaves a bus open."""

from __future__ import annotations

import os
from pathlib import Path

import can.interfaces.virtual as virtual
import pytest
from hypothesis import HealthCheck, settings

ROOT = Path(__file__).resolve().parents[1]
IN_CI = os.environ.get("CI", "").lower() == "true"

# Tests never assert wall-clock times: no Hypothesis deadlines. CI runs more examples.
settings.register_profile("dev", deadline=None, max_examples=200, suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("ci", deadline=None, max_examples=500, suppress_health_check=[HealthCheck.too_slow])
settings.load_profile("ci" if IN_CI else "dev")


def vcan_problem() -> str | None:
    """Why the vcan tests cannot run here, or None."""
    reason = os.environ.get("AIDER_VCAN_UNAVAILABLE")
    if reason:
        return reason
    if not Path("/sys/class/net/vcan0").exists():
        return "no vcan0 interface (run these tests through tools/vcan-run, as `make test` does)"
    from protocol.bus import socketcan_problem

    return socketcan_problem("vcan0")


@pytest.fixture
def vcan0() -> str:
    """The name of a usable SocketCAN interface; skips loudly (fails under CI=true) without one."""
    problem = vcan_problem()
    if problem:
        message = f"VCAN TESTS NOT RUN: {problem}"
        if IN_CI:
            pytest.fail(message + " (CI=true requires them)", pytrace=False)
        pytest.skip(message)
    return "vcan0"


def udp_group(channel: str) -> tuple[str, int]:
    """The (group, port) of a udp_multicast channel, parsed as the configuration parses it."""
    from config.schema import BusConfig

    return BusConfig(interface="udp_multicast", channel=channel, bitrate_bit_s=1_000_000).udp_group()


def udp_multicast_problem(channel: str) -> str | None:
    """Why two buses on the UDP multicast ``channel`` do not hear each other here, or None."""
    import can

    from protocol.bus import UdpBus

    group, port = udp_group(channel)
    try:
        with UdpBus(group, port) as a, UdpBus(group, port) as b:
            a.send(can.Message(arbitration_id=0x7FF, data=b"probe", is_extended_id=False))
            if b.recv(timeout=2.0) is None:
                return f"a frame sent to {channel} did not come back over the loopback"
    except (OSError, can.CanError) as exc:
        return f"cannot join the UDP multicast group {channel}: {exc} (sudo ip route add 224.0.0.0/4 dev lo)"
    return None


@pytest.fixture
def udp_multicast() -> str:
    """A UDP multicast channel (group:port, a free port of its own) that works on this machine;
    skips loudly (fails under CI=true) without multicast."""
    from protocol.bus import free_udp_channel

    channel = free_udp_channel()  # each test a port of its own
    problem = udp_multicast_problem(channel)
    if problem:
        message = f"UDP MULTICAST TESTS NOT RUN: {problem}"
        if IN_CI:
            pytest.fail(message + " (CI=true requires them)", pytrace=False)
        pytest.skip(message)
    return channel


@pytest.fixture(autouse=True)
def _no_virtual_bus_left_open():
    """Like python-can's own suite: a test that leaves a virtual bus open fails."""
    before = {name: len(queues) for name, queues in virtual.channels.items()}
    yield
    leaked = {name: len(q) - before.get(name, 0) for name, q in virtual.channels.items() if len(q) > before.get(name, 0)}
    assert not leaked, f"virtual bus left open (call shutdown() or use `with`): {leaked}"
