"""Opening the configured bus; the clock abstraction and absolute-deadline tick pacing."""

from __future__ import annotations

import socket

import can
import pytest

from config import BusConfig
from protocol.bus import InProcessBus, open_bus, send_of, socketcan_problem, virtual_bus
from protocol.clock import ManualClock, TickTimer
from protocol.errors import BusUnavailableError


def test_virtual_bus_opens_and_carries_frames():
    cfg = BusConfig(interface="virtual", channel="t-bus", bitrate_bit_s=500_000)
    with open_bus(cfg) as a, open_bus(cfg) as b:
        a.send(can.Message(arbitration_id=0x80, data=b"\x01", is_extended_id=False))
        msg = b.recv(timeout=1)
        assert msg is not None and msg.arbitration_id == 0x80


def test_in_process_bus_delivers_as_python_cans_virtual_bus():
    """Same channel, receivers, own-message rule, timestamps and flags as VirtualBus; each
    receiver gets its own copy of the data; both classes on one channel see each other."""
    with virtual_bus("t-fast") as a, virtual_bus("t-fast", receive_own_messages=True) as b, \
            can.Bus(interface="virtual", channel="t-fast", ignore_config=True) as plain:
        assert isinstance(a, InProcessBus) and isinstance(a, can.interfaces.virtual.VirtualBus)
        sent = can.Message(arbitration_id=0x123, data=b"\x01\x02", is_extended_id=False, timestamp=5.0)
        a.send(sent)
        sent.data[0] = 0xFF  # the sender's buffer is not the receivers'
        got_b, got_plain = b.recv(timeout=1), plain.recv(timeout=1)
        assert a.recv(timeout=0) is None  # not its own message
        for got in (got_b, got_plain):
            assert got is not None and got is not sent
            assert (got.arbitration_id, bytes(got.data), got.dlc, got.is_extended_id) == (0x123, b"\x01\x02", 2, False)
            assert got.channel == "t-fast" and got.is_rx and got.timestamp != 5.0
        assert got_b.data is not got_plain.data
        b.send(can.Message(arbitration_id=0x7, data=b"", is_extended_id=False))
        own = b.recv(timeout=1)
        assert own is not None and own.arbitration_id == 0x7 and not own.is_rx
        assert a.recv(timeout=1).arbitration_id == 0x7 and plain.recv(timeout=1).arbitration_id == 0x7
        plain.send(can.Message(arbitration_id=0x8, data=b"\x09", is_extended_id=False))
        assert a.recv(timeout=1).arbitration_id == 0x8


def test_in_process_send_owned_hands_the_message_to_one_receiver_and_copies_for_the_rest():
    """A message made for one send is handed over, not copied, to one receiver, stamped as a copy
    would be; every other receiver gets its own copy; with a bounded receiving queue (a put that
    can fail) it is an ordinary send. ``send_of`` picks it for in-process buses only."""
    with virtual_bus("t-owned") as a, virtual_bus("t-owned") as b:
        assert send_of(a) == a.send_owned
        sent = can.Message(arbitration_id=0x181, data=b"\x01\x02", is_extended_id=False)
        a.send_owned(sent)
        got = b.recv(timeout=1)
        assert got is sent and got.channel == "t-owned" and got.is_rx and got.timestamp > 0
        assert a.recv(timeout=0) is None
        with virtual_bus("t-owned") as c:
            a.send_owned(can.Message(arbitration_id=0x182, data=b"\x03", is_extended_id=False))
            got_b, got_c = b.recv(timeout=1), c.recv(timeout=1)
            assert (got_b.arbitration_id, bytes(got_b.data)) == (got_c.arbitration_id, bytes(got_c.data)) == (0x182, b"\x03")
            assert got_b is not got_c and got_b.data is not got_c.data
    with virtual_bus("t-owned-bounded") as a, virtual_bus("t-owned-bounded", rx_queue_size=4) as bounded:
        sent = can.Message(arbitration_id=0x183, data=b"\x04", is_extended_id=False)
        a.send_owned(sent)
        got = bounded.recv(timeout=1)
        assert got is not sent and bytes(got.data) == b"\x04"
    with open_bus(BusConfig(interface="virtual", channel="t-owned-plain", bitrate_bit_s=500_000)) as a:
        assert send_of(a) == a.send_owned
    with can.Bus(interface="virtual", channel="t-owned-plain", ignore_config=True) as plain:  # python-can's own class
        assert send_of(plain) == plain.send


def _udp(channel: str, **kwargs) -> can.BusABC:
    return open_bus(BusConfig(interface="udp_multicast", channel=channel, bitrate_bit_s=1_000_000, **kwargs))


def _frame(can_id: int, data: bytes = b"") -> can.Message:
    return can.Message(arbitration_id=can_id, data=data, is_extended_id=False)


def test_udp_multicast_carries_frames_between_buses_without_their_own_echo(udp_multicast):
    """As on SocketCAN: a sender does not receive its own frames (multicast loops every datagram
    back; the bus drops the echoes), unless receive_own_messages asks for them; every other bus
    on the group gets every frame, in order."""
    with _udp(udp_multicast) as a, _udp(udp_multicast) as b, _udp(udp_multicast, receive_own_messages=True) as own:
        a.send(_frame(0x80, b"\x01"))
        a.send(_frame(0x80, b"\x01"))  # the same bytes twice: two echoes to drop, two frames for the others
        b.send(_frame(0x81, b"\x02"))
        own.send(_frame(0x82))
        got = {name: [] for name in "ab"}
        for name, bus in (("a", a), ("b", b)):
            while (m := bus.recv(timeout=0.5)) is not None:
                got[name].append((m.arbitration_id, bytes(m.data)))
        assert got["a"] == [(0x81, b"\x02"), (0x82, b"")]
        assert got["b"] == [(0x80, b"\x01"), (0x80, b"\x01"), (0x82, b"")]
        heard = []
        while (m := own.recv(timeout=0.5)) is not None:
            heard.append(m.arbitration_id)
        assert heard == [0x80, 0x80, 0x81, 0x82]


def test_a_udp_multicast_listener_not_run_for_a_moment_keeps_a_burst(udp_multicast):
    """The receive buffer of our SocketCAN sockets (about 1100 frames) on the UDP bus too: a
    lock-step walk's burst waits for a listener that was not run, instead of being dropped."""
    import os
    import socket

    from protocol.bus import RECEIVE_BUFFER_BYTES

    with _udp(udp_multicast) as sender, _udp(udp_multicast) as listener:
        with socket.fromfd(listener.inner.fileno(), socket.AF_INET, socket.SOCK_DGRAM) as sock:
            granted = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        expected = RECEIVE_BUFFER_BYTES if os.geteuid() == 0 else min(RECEIVE_BUFFER_BYTES, int(open("/proc/sys/net/core/rmem_max").read()))
        assert granted >= 2 * expected, granted  # the kernel reports twice what it grants
        if expected < RECEIVE_BUFFER_BYTES:
            return  # capped by net.core.rmem_max for this user: the burst below would overflow it
        burst = 600  # the kernel's default buffer holds about 230
        for i in range(burst):
            sender.send(_frame(0x100 + i % 0x100, i.to_bytes(2, "little")))
        got = 0
        while listener.recv(timeout=0.5) is not None:
            got += 1
        assert got == burst


def test_udp_multicast_poll_reads_past_echoes_and_counts_garbage(udp_multicast):
    """A poll (timeout 0) skips echoes and foreign datagrams to the frame behind them: the
    controller's drain takes an empty poll for an empty bus (a poll that returned nothing at an
    echo left the nodes' frames unread: ENCODER_STUCK in a real-time walk). A datagram that is
    not a packed frame is counted, never raised."""
    group, _, port = udp_multicast.partition(":")
    with _udp(udp_multicast) as a, _udp(udp_multicast) as b, _udp(udp_multicast) as witness, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as raw:

        def delivered(last_id: int) -> None:
            """Until the witness has the last datagram sent (multicast on the loopback reaches
            every socket of the group together)."""
            while (m := witness.recv(timeout=1.0)) is not None and m.arbitration_id != last_id:
                pass
            assert m is not None, f"0x{last_id:X} did not come"

        a.send(_frame(0x10))
        raw.sendto(b"not a frame", (group, int(port)))
        b.send(_frame(0x11))
        delivered(0x11)
        msg = a.recv(timeout=0)  # behind its own echo and the garbage
        assert msg is not None and msg.arbitration_id == 0x11
        assert b.recv(timeout=0).arbitration_id == 0x10 and b.recv(timeout=0) is None
        a.send(_frame(0x12))
        delivered(0x12)
        assert a.recv(timeout=0) is None  # only its echo was there
        assert a.undecodable == 1 and b.undecodable == 1 and witness.undecodable == 1


def test_missing_socketcan_gives_one_line_with_fixes(monkeypatch):
    monkeypatch.setattr("protocol.bus.socketcan_problem", lambda channel: "this kernel has no SocketCAN")
    cfg = BusConfig(interface="socketcan", channel="vcan0", bitrate_bit_s=500_000)
    with pytest.raises(BusUnavailableError) as info:
        open_bus(cfg)
    text = str(info.value)
    assert "\n" not in text
    for fix in ("modprobe vcan", "tools/vcan-run", "bus.interface: virtual"):
        assert fix in text


def test_socketcan_problem_names_the_cause(tmp_path, monkeypatch):
    class FakeSocket:
        def __init__(self, *args):
            pass

        def close(self):
            pass

    monkeypatch.setattr(socket, "AF_CAN", getattr(socket, "AF_CAN", 29), raising=False)
    monkeypatch.setattr(socket, "socket", FakeSocket)
    assert "no network interface 'vcan7'" in socketcan_problem("vcan7", tmp_path)
    (tmp_path / "vcan7").mkdir()
    (tmp_path / "vcan7" / "flags").write_text("0x80\n")
    assert "is down" in socketcan_problem("vcan7", tmp_path)
    (tmp_path / "vcan7" / "flags").write_text("0xc1\n")
    assert socketcan_problem("vcan7", tmp_path) is None


def test_this_kernel_without_af_can_is_detected():
    try:
        socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW).close()
    except OSError:
        assert "no SocketCAN" in socketcan_problem("vcan0")
    else:
        pytest.skip("this kernel has SocketCAN")


def test_manual_clock():
    clock = ManualClock(100)
    clock.sleep_until(50)
    assert clock.now_ns() == 100
    clock.sleep_until(250)
    assert clock.now_ns() == 250
    with pytest.raises(ValueError):
        clock.advance(-1)


def test_tick_timer_keeps_absolute_deadlines():
    clock = ManualClock(1_000)
    timer = TickTimer(clock, period_ns=20)
    ticks = []
    for _ in range(5):
        ticks.append(timer.wait())
        clock.advance(7)  # work shorter than a tick
    assert ticks == [0, 1, 2, 3, 4]
    assert clock.now_ns() == 1_000 + 4 * 20 + 7
    assert timer.overruns == 0


def test_tick_timer_skips_missed_ticks_without_a_burst():
    clock = ManualClock(0)
    timer = TickTimer(clock, period_ns=20)
    assert timer.wait() == 0
    clock.advance(65)  # overran ticks 1, 2 and 3
    assert timer.wait() == 4 and clock.now_ns() == 80
    assert timer.overruns == 1 and timer.skipped == 3
    clock.advance(5)
    assert timer.wait() == 5 and clock.now_ns() == 100
