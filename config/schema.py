"""Schema of the aider-exo configuration file.

One frozen dataclass per section; :class:`Config` is the root. Each
component receives only its own section (the bus gets ``config.bus``, the E2E
receiver gets ``config.protocol``), never the whole :class:`Config`.

Adding a section: define a frozen, ``kw_only`` dataclass whose fields are all
declared with :func:`~config.loader.field_spec` (with a ``doc``; units in the
names), put cross-field checks in a ``validate()`` method that reports with
:func:`~config.loader.fail`, add it as a field of :class:`Config`, and list
every key with a comment in ``default.yaml``. Safety parameters get no
default, so a file that forgets them is rejected.
"""

from __future__ import annotations

import ipaddress
import re
import dataclasses
from dataclasses import dataclass
from typing import Literal

from .loader import fail, field_spec
from .controller_schema import ControllerConfig
from .hardware_schema import HardwareConfig
from .nodes_schema import NodesConfig
from .sim_schema import SimConfig

__all__ = ["SCHEMA_VERSION", "BusConfig", "Config", "ProtocolConfig"]

#: Version of the file format this program reads (``schema_version`` key).
SCHEMA_VERSION = 1

#: python-can's UDP multicast port (can.interfaces.udp_multicast.UdpMulticastBus.DEFAULT_PORT)
UDP_DEFAULT_PORT = 43113

# Linux network interface names: at most IFNAMSIZ - 1 = 15 bytes; we accept the
# portable subset of characters.
_LINUX_IFNAME = re.compile(r"[A-Za-z0-9_.-]{1,15}")


@dataclass(frozen=True, kw_only=True)
class BusConfig:
    """CAN bus that the controller and the nodes attach to.

    Attributes
    ----------
    interface : {"socketcan", "virtual", "udp_multicast"}
        Bus backend.
    channel : str
        Interface name (socketcan), bus name (virtual) or multicast group (udp_multicast).
    bitrate_bit_s : int
        Nominal bitrate in bit/s, for bus-load figures.
    receive_own_messages : bool
        Whether a sender also receives its own frames.
    """

    interface: Literal["socketcan", "virtual", "udp_multicast"] = field_spec(
        doc=(
            "Bus backend: 'socketcan' for a Linux SocketCAN interface (vcan0, can0), "
            "'virtual' for an in-process bus shared by everything in one process, "
            "'udp_multicast' for python-can's CAN-over-UDP-multicast bus between processes "
            "or hosts without CAN hardware (simulation and hardware-in-the-loop only: no "
            "arbitration, no delivery guarantee)."
        ),
    )
    channel: str = field_spec(
        doc=(
            "For socketcan the Linux interface name (at most 15 characters from "
            "A-Z a-z 0-9 _ . -), e.g. vcan0 or can0; for virtual any non-empty name, "
            "users of the same name share one bus; for udp_multicast a multicast group, "
            "IPv4 or IPv6, with an optional port: 239.74.163.2, 239.74.163.2:43114, "
            "[ff15:7079:7468:6f6e:6465:6d6f:6d63:6173]:43114 (default port 43113)."
        ),
    )
    bitrate_bit_s: int = field_spec(
        doc=(
            "Nominal bitrate, used to compute bus-load figures. On socketcan the "
            "interface bitrate is configured with `ip link set <channel> type can "
            "bitrate ...`, not by this program; keep both equal."
        ),
        unit="bit/s",
        min=10_000,
        max=1_000_000,
    )
    receive_own_messages: bool = field_spec(
        doc="Deliver frames sent through this bus connection back to its own receivers.",
        default=False,
    )

    def validate(self) -> None:
        """Check the channel name against the interface."""
        if not self.channel.strip():
            fail("channel", "must not be empty")
        if self.interface == "socketcan" and (
            not _LINUX_IFNAME.fullmatch(self.channel) or self.channel in (".", "..")
        ):
            shown = repr(self.channel if len(self.channel) <= 40 else self.channel[:40] + "...")
            fail(
                "channel",
                f"{shown} is not a valid Linux interface name for socketcan "
                "(1 to 15 characters from A-Z a-z 0-9 _ . -)",
            )
        if self.interface == "udp_multicast":
            self.udp_group()

    def udp_group(self) -> tuple[str, int]:
        """The multicast group and port of a udp_multicast ``channel`` (fails naming the key)."""
        text = self.channel.strip()
        host, port = text, UDP_DEFAULT_PORT
        if text.startswith("["):  # [IPv6]:port
            host, sep, rest = text[1:].partition("]")
            if not sep or (rest and not rest.startswith(":")):
                fail("channel", f"{text!r}: an IPv6 group with a port is written [group]:port")
            port_text = rest[1:] if rest else None
        elif text.count(":") == 1:  # IPv4:port
            host, _, port_text = text.partition(":")
        else:
            port_text = None
        if port_text is not None:
            if not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
                fail("channel", f"{text!r}: the port must be a number from 1 to 65535")
            port = int(port_text)
        try:
            group = ipaddress.ip_address(host)
        except ValueError:
            fail("channel", f"{text!r} is not an IPv4 or IPv6 address (udp_multicast needs a multicast group)")
        if not group.is_multicast:
            fail("channel", f"{host} is not a multicast address (IPv4 224.0.0.0/4, IPv6 ff00::/8)")
        return str(group), port


@dataclass(frozen=True, kw_only=True)
class ProtocolConfig:
    """Settings of the end-to-end (E2E) protection receiver.

    Attributes
    ----------
    max_delta_counter : int
        AUTOSAR E2E Profile 1 ``MaxDeltaCounter``.
    """

    max_delta_counter: int = field_spec(
        doc=(
            "AUTOSAR E2E Profile 1 MaxDeltaCounter: how far the 4-bit alive counter "
            "(0..14) may advance between two accepted frames of one message. "
            "1 means no frame may be lost; a larger jump is reported as lost frames."
        ),
        min=1,
        max=14,
    )


@dataclass(frozen=True, kw_only=True)
class Config:
    """Root of the aider-exo configuration.

    Attributes
    ----------
    schema_version : int
        File format version; must be :data:`SCHEMA_VERSION`.
    bus : BusConfig
        CAN bus settings.
    protocol : ProtocolConfig
        E2E receiver settings.
    """

    # First field: a file of another version is reported as such before any
    # of its other keys are looked at.
    schema_version: int = field_spec(
        doc="Version of the configuration file format; this program reads version 1.",
        choices=(SCHEMA_VERSION,),
    )
    bus: BusConfig = field_spec(doc="CAN bus settings.")
    protocol: ProtocolConfig = field_spec(doc="End-to-end protection receiver settings.")
    hardware: HardwareConfig | None = field_spec(
        doc="The exoskeleton and its sticks, one physical fact each: what the controller and the simulation both read.",
        default=None,
    )
    controller: ControllerConfig | None = field_spec(
        doc="The main controller's algorithms (legs, swing DMP, step bounds, learning).", default=None
    )
    sim: SimConfig | None = field_spec(
        doc="The simulated HHEA (model, physics, patient, sensors); absent on the robot.", default=None
    )
    nodes: NodesConfig | None = field_spec(
        doc="The emulated node boards (watchdogs, fault injection); absent on the robot.", default=None
    )

    def __post_init__(self) -> None:
        # The hardware section is one definition; the controller and the simulation each read it
        # as their own ``hardware`` (a derived field: never in their sections of a file).
        for name in ("controller", "sim"):
            section = getattr(self, name)
            if section is not None and section.hardware is not self.hardware:
                object.__setattr__(self, name, dataclasses.replace(section, hardware=self.hardware))

    def validate(self) -> None:
        if self.hardware is None and (self.controller is not None or self.sim is not None):
            fail("hardware", "missing required key (the controller and the simulation read the exoskeleton from it)")
        if self.sim is not None:
            p, stick_m = self.sim.model.patient, self.hardware.sticks.length_m
            shoulder_z = p.shoulder_height_fraction * p.height_m
            reach = (p.upper_arm.length_fraction + p.forearm.length_fraction) * p.height_m
            reach += p.hand.com_fraction * p.hand.length_fraction * p.height_m + stick_m
            if reach < shoulder_z:  # even standing straight the straight arm puts the tip on the floor
                fail("hardware.sticks.length_m",
                     f"the sticks cannot reach the ground: arm plus stick reach {reach:.2f} m, shoulders at {shoulder_z:.2f} m")
