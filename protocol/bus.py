"""Open the CAN bus named by the configuration (python-can; never its hidden global config).

python-can's :class:`can.BusABC` is the transport abstraction and its ``virtual`` bus the
in-process fake; this module only turns a :class:`config.BusConfig` into an open bus, and a
missing SocketCAN into one line that says how to get it.
"""

from __future__ import annotations

import errno
import socket
from pathlib import Path

import can

from config import BusConfig
from protocol.errors import BusUnavailableError

_FIXES = (
    "fixes: `sudo modprobe vcan && sudo ip link add dev vcan0 type vcan && sudo ip link set up vcan0`, "
    "or run the command under `tools/vcan-run --` (user-mode Linux), or set bus.interface: virtual"
)


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
        return can.Bus(
            interface="virtual",
            channel=cfg.channel,
            receive_own_messages=cfg.receive_own_messages,
            ignore_config=True,
        )
    problem = socketcan_problem(cfg.channel)
    if problem is not None:
        raise BusUnavailableError(f"cannot open socketcan channel {cfg.channel!r}: {problem}; {_FIXES}")
    try:
        return can.Bus(
            interface="socketcan",
            channel=cfg.channel,
            receive_own_messages=cfg.receive_own_messages,
            ignore_config=True,
        )
    except (OSError, can.CanError) as exc:
        raise BusUnavailableError(f"cannot open socketcan channel {cfg.channel!r}: {exc}; {_FIXES}") from None
