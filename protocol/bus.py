"""Open the CAN bus named by the configuration (python-can; never its hidden global config).

python-can's :class:`can.BusABC` is the transport abstraction, its ``virtual`` bus the
in-process fake and its ``udp_multicast`` bus CAN between processes or hosts without CAN
hardware; this module only turns a :class:`config.BusConfig` into an open bus, and a missing
SocketCAN (or multicast) into one line that says how to get it.
"""

from __future__ import annotations

import errno
import queue
import socket
from collections import Counter, deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import can
from can.bus import LOG as _LOG
from can.interfaces.virtual import VirtualBus, channels_lock

from config import BusConfig
from protocol.clock import MonotonicClock, epoch_s
from config.errors import AiderError
from protocol.errors import BusUnavailableError

_FIXES = (
    "fixes: `sudo modprobe vcan && sudo ip link add dev vcan0 type vcan && sudo ip link set up vcan0`, "
    "or run the command under `tools/vcan-run --` (user-mode Linux), or set bus.interface: virtual"
)


class InProcessBus(VirtualBus):
    """python-can's virtual bus (same channels, receive queues, timestamps and errors; buses of
    either class on one channel see each other) whose ``send`` copies a message cheaply.

    :class:`~can.interfaces.virtual.VirtualBus` deep-copies every message once per receiver
    (``copy.deepcopy``: about 15 us a frame, a sixth of an in-process walk's bus time); this
    copies the fields and the data bytes, which is all a deep copy of a message holds. An
    unbounded receive queue (``rx_queue_size`` 0, the default) is a :class:`queue.SimpleQueue`
    (C, one lock) instead of VirtualBus's :class:`queue.Queue` (three conditions per put and get);
    both are FIFO and thread-safe, and a bounded queue stays VirtualBus's. A receive with timeout
    0 (a poll, as the lock-step walk does) without filters takes the queue's head without
    :meth:`can.BusABC.recv`'s deadline loop.
    """

    def __init__(self, channel: Any = "channel-0", **kwargs: Any) -> None:
        super().__init__(channel=channel, **kwargs)
        if not kwargs.get("rx_queue_size", 0):
            with channels_lock:
                fast: queue.SimpleQueue[can.Message] = queue.SimpleQueue()
                self.channel[self.channel.index(self.queue)] = fast
                self.queue = fast  # type: ignore[assignment]  # same put/get/get_nowait

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if timeout != 0 or self._filters is not None:
            return super().recv(timeout)
        self._check_if_open()
        try:  # a poll: what BusABC.recv returns for timeout 0 without filters
            msg = self.queue.get_nowait()
        except queue.Empty:
            return None
        if _LOG.isEnabledFor(self.RECV_LOGGING_LEVEL):  # what Logger.log asks first, without its call
            _LOG.log(self.RECV_LOGGING_LEVEL, "Received: %s", msg)
        return msg

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if timeout != 0:
            return super()._recv_internal(timeout)
        self._check_if_open()
        try:  # a poll: the same as VirtualBus's get(timeout=0), without its deadline arithmetic
            return self.queue.get_nowait(), False
        except queue.Empty:
            return None, False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._deliver(msg, timeout, None)

    def send_owned(self, msg: can.Message, timeout: float | None = None) -> None:
        """:meth:`send` of a message made for this one send, which the caller does not touch
        again: one receiver gets ``msg`` itself (its timestamp, channel and ``is_rx`` set as on
        a copy), the others copies made before it is handed over. In a lock-step walk the copy
        was 5-7 % of the pipeline's cost beside the simulation (measured). When a receiving
        queue is bounded (a put that can fail, and a retried send would hand the message over
        twice) it is :meth:`send`."""
        keep = None
        for bus_queue in self.channel:
            if bus_queue is self.queue and not self.receive_own_messages:
                continue
            if type(bus_queue) is not queue.SimpleQueue:
                keep = None
                break
            keep = bus_queue
        self._deliver(msg, timeout, keep)

    def _deliver(self, msg: can.Message, timeout: float | None, keep: Any) -> None:
        """Put a copy of ``msg`` on every receiving queue but ``keep``, then ``msg`` itself on ``keep``."""
        self._check_if_open()
        timestamp = msg.timestamp if self.preserve_timestamps else epoch_s()
        all_sent = True
        for bus_queue in self.channel:
            if bus_queue is keep or (bus_queue is self.queue and not self.receive_own_messages):
                continue
            msg_copy = can.Message(
                timestamp=timestamp, arbitration_id=msg.arbitration_id, is_extended_id=msg.is_extended_id,
                is_remote_frame=msg.is_remote_frame, is_error_frame=msg.is_error_frame, channel=self.channel_id,
                dlc=msg.dlc, data=bytearray(msg.data), is_fd=msg.is_fd, is_rx=bus_queue is not self.queue,
                bitrate_switch=msg.bitrate_switch, error_state_indicator=msg.error_state_indicator,
            )
            try:
                bus_queue.put(msg_copy, block=True, timeout=timeout)
            except queue.Full:
                all_sent = False
        if keep is not None:
            msg.timestamp, msg.channel, msg.is_rx = timestamp, self.channel_id, keep is not self.queue
            keep.put(msg)
        if not all_sent:
            raise can.CanOperationError("Could not send message to one or more recipients")


def send_of(bus: can.BusABC) -> Callable[[can.Message], None]:
    """How a sender that makes each message for one send and never touches it again sends on
    ``bus``: :meth:`InProcessBus.send_owned` in process (no copy), the bus's ``send`` elsewhere."""
    return bus.send_owned if isinstance(bus, InProcessBus) else bus.send


def virtual_bus(channel: str, **kwargs: Any) -> InProcessBus:
    """An in-process virtual bus on ``channel`` (:class:`InProcessBus`; what ``can.Bus(interface=
    "virtual", channel=channel, ignore_config=True, **kwargs)`` opens, with the cheaper send)."""
    return InProcessBus(channel=channel, **kwargs)


#: own frames a :class:`UdpBus` remembers until their echo comes back (over a second of the nodes' sends)
ECHO_WINDOW = 1024


def _frame_key(msg: can.Message) -> tuple[int, bool, bool, bytes]:
    return msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame, bytes(msg.data)


class ListenOnly:
    """A bus that can only be read: ``recv`` and ``shutdown`` reach it, ``send`` never does (it
    raises :attr:`error` with :attr:`REFUSAL` and is counted in ``sends_refused``). A passive tool's
    only bus handle, so no code path of it transmits; subclasses say whose and raise their own error."""

    REFUSAL = "a passive listener never sends a frame"
    error: type[Exception] = AiderError

    def __init__(self, bus: can.BusABC) -> None:
        self._bus = bus
        self.sends_refused = 0

    def recv(self, timeout: float | None = None) -> can.Message | None:
        return self._bus.recv(timeout)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.sends_refused += 1
        raise self.error(self.REFUSAL)

    def shutdown(self) -> None:
        self._bus.shutdown()


#: python-can's default IPv4 multicast group; a run of its own takes a free port on it
UDP_GROUP = "239.74.163.2"


def free_udp_channel() -> str:
    """A ``udp_multicast`` channel (``group:port``) on a port no socket of this host holds now."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("", 0))
        return f"{UDP_GROUP}:{s.getsockname()[1]}"


class UdpBus(can.BusABC):
    """python-can's UDP multicast bus (classic frames) with SocketCAN's semantics for our own
    frames and for garbage.

    Multicast loops every datagram back to its sender, so python-can's bus receives its own
    frames whatever ``receive_own_messages`` says. Unless asked for them, this drops the echo of
    each frame it sent: a received frame equal to one it sent whose echo has not come yet is that
    echo (the newest :data:`ECHO_WINDOW` sent are remembered, so an echo that never comes is
    forgotten). Another sender's frame with the very bytes of one of ours still waiting for its
    echo would be taken for it; on our protocol that is a frame on our ID with our counter and
    CRC, which only a fault sends. A datagram on the group that is not a packed CAN frame (another
    program on the same group and port) is counted in :attr:`undecodable` and skipped, not
    raised from ``recv``; the socket's own errors are raised as python-can raises them.
    """

    def __init__(self, group: str, port: int, *, receive_own_messages: bool = False) -> None:
        from can.interfaces.udp_multicast import UdpMulticastBus

        self.inner = UdpMulticastBus(channel=group, port=port, fd=False)
        # The receive buffer of SocketCAN's sockets here too: a lock-step walk sends far faster than
        # real time, and a listener not run for a moment lost datagrams (a counter gap) to the default.
        with socket.fromfd(self.inner.fileno(), socket.AF_INET, socket.SOCK_DGRAM) as sock:  # a duplicate descriptor
            _set_receive_buffer(sock)
        super().__init__(channel=f"{group}:{port}")
        self.channel_info = f"UDP multicast {group} port {port}"
        self.receive_own_messages = receive_own_messages
        self._sent: Counter[tuple[int, bool, bool, bytes]] = Counter()
        self._order: deque[tuple[int, bool, bool, bytes]] = deque()
        self.undecodable = 0
        self._clock = MonotonicClock()

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.inner.send(msg, timeout)
        if self.receive_own_messages:
            return
        key = _frame_key(msg)
        self._sent[key] += 1
        self._order.append(key)
        if len(self._order) > ECHO_WINDOW:
            self._forget(self._order.popleft())

    def _forget(self, key: tuple[int, bool, bool, bytes]) -> None:
        self._sent[key] -= 1
        if not self._sent[key]:
            del self._sent[key]

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        """The next frame that is not our own echo nor garbage, within ``timeout``: what is
        skipped never ends the wait early (a poll with timeout 0 reads on while datagrams are
        queued; the controller's drain takes an empty poll for an empty bus)."""
        clock = self._clock
        deadline = None if timeout is None else clock.now_ns() + int(timeout * 1e9)
        while True:
            left = None if deadline is None else max(0, deadline - clock.now_ns()) / 1e9
            try:
                msg, filtered = self.inner._recv_internal(left)
            except can.CanOperationError as exc:
                if exc.__cause__ is None or isinstance(exc.__cause__, OSError):
                    raise  # the socket's error, not a datagram's
                self.undecodable += 1  # a datagram that does not unpack to a frame
                continue
            if msg is None:
                return None, False
            key = _frame_key(msg)
            if key not in self._sent:
                return msg, filtered
            self._forget(key)  # our own frame's echo
            if self._order[0] == key:
                self._order.popleft()
            else:
                self._order.remove(key)

    def fileno(self) -> int:
        return self.inner.fileno()

    def shutdown(self) -> None:
        super().shutdown()
        self.inner.shutdown()


def socketcan_problem(channel: str, sys_class_net: Path = Path("/sys/class/net")) -> str | None:
    """Why SocketCAN ``channel`` cannot be used here, or None when it looks usable."""
    family = getattr(socket, "AF_CAN", None)
    if family is None:
        return "this platform has no SocketCAN (socket.AF_CAN missing)"
    try:
        socket.socket(family, socket.SOCK_RAW, socket.CAN_RAW).close()
    except OSError as exc:
        if exc.errno == errno.EAFNOSUPPORT:
            return "this kernel has no SocketCAN (AF_CAN: address family not supported)"
        return f"cannot create a CAN socket ({exc.strerror or exc})"
    iface = sys_class_net / channel
    if not iface.exists():
        return f"there is no network interface {channel!r}"
    try:
        flags = int((iface / "flags").read_text().strip(), 16)
    except (OSError, ValueError):
        flags = 1
    if not flags & 0x1:  # IFF_UP
        return f"interface {channel!r} is down (sudo ip link set up {channel})"
    return None


def open_bus(cfg: BusConfig) -> can.BusABC:
    """Open the bus of ``cfg``; raises :class:`BusUnavailableError` with a one-line reason and fixes."""
    if cfg.interface == "virtual":
        return virtual_bus(cfg.channel, receive_own_messages=cfg.receive_own_messages)
    if cfg.interface == "udp_multicast":
        group, port = cfg.udp_group()
        try:
            return UdpBus(group, port, receive_own_messages=cfg.receive_own_messages)
        except (OSError, can.CanError) as exc:
            raise BusUnavailableError(
                f"cannot join the UDP multicast group {group} port {port}: {exc}; without a network, "
                "a multicast route on the loopback interface gives one: `sudo ip route add 224.0.0.0/4 dev lo`"
            ) from None
    problem = socketcan_problem(cfg.channel)
    if problem is not None:
        raise BusUnavailableError(f"cannot open socketcan channel {cfg.channel!r}: {problem}; {_FIXES}")
    try:
        bus = can.Bus(
            interface="socketcan",
            channel=cfg.channel,
            receive_own_messages=cfg.receive_own_messages,
            ignore_config=True,
        )
    except (OSError, can.CanError) as exc:
        raise BusUnavailableError(f"cannot open socketcan channel {cfg.channel!r}: {exc}; {_FIXES}") from None
    _enlarge_receive_buffer(bus)
    return bus


SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)  # Linux; Python's socket module lacks the name

#: The socket's receive buffer: about 1100 classic frames (a kernel skb of a CAN frame takes about
#: 900 bytes), 1.2 s of our traffic and the floods of the vcan tests. The kernel's default (212992
#: bytes, about 230 frames) overflowed when a process was not run for a moment during a flood, and
#: frames were lost (a counter gap), as candump's -r option exists for.
RECEIVE_BUFFER_BYTES = 1 << 20


def _enlarge_receive_buffer(bus: can.BusABC) -> None:
    sock = getattr(bus, "socket", None)
    if sock is not None:
        _set_receive_buffer(sock)


def _set_receive_buffer(sock: socket.socket) -> None:
    """:data:`RECEIVE_BUFFER_BYTES`, past ``net.core.rmem_max`` where the process may
    (``SO_RCVBUFFORCE``, CAP_NET_ADMIN), else up to it (the kernel caps ``SO_RCVBUF`` silently)."""
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, RECEIVE_BUFFER_BYTES)
    except OSError:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER_BYTES)
