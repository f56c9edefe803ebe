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

import re
from dataclasses import dataclass
from typing import Literal

from .loader import fail, field_spec
from .controller_schema import ControllerConfig
from .nodes_schema import NodesConfig
from .sim_schema import SimConfig

__all__ = ["SCHEMA_VERSION", "BusConfig", "Config", "ProtocolConfig"]

#: Version of the file format this program reads (``schema_version`` key).
SCHEMA_VERSION = 1

# Linux network interface names: at most IFNAMSIZ - 1 = 15 bytes; we accept the
# portable subset of characters.
_LINUX_IFNAME = re.compile(r"[A-Za-z0-9_.-]{1,15}")


@dataclass(frozen=True, kw_only=True)
class BusConfig:
    """CAN bus that the controller and the nodes attach to.

    Attributes
    ----------
    interface : {"socketcan", "virtual"}
        Bus backend.
    channel : str
        Interface name (socketcan) or bus name (virtual).
    bitrate_bit_s : int
        Nominal bitrate in bit/s, for bus-load figures.
    receive_own_messages : bool
        Whether a sender also receives its own frames.
    """

    interface: Literal["socketcan", "virtual"] = field_spec(
        doc=(
            "Bus backend: 'socketcan' for a Linux SocketCAN interface (vcan0, can0), "
            "'virtual' for an in-process bus shared by everything in one process."
        ),
    )
    channel: str = field_spec(
        doc=(
            "For socketcan the Linux interface name (at most 15 characters from "
            "A-Z a-z 0-9 _ . -), e.g. vcan0 or can0; for virtual any non-empty name, "
            "users of the same name share one bus."
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
    controller: ControllerConfig | None = field_spec(
        doc="The main controller's algorithms (legs, swing DMP, step bounds, learning).", default=None
    )
    sim: SimConfig | None = field_spec(
        doc="The simulated HHEA (model, physics, patient, sensors); absent on the robot.", default=None
    )
    nodes: NodesConfig | None = field_spec(
        doc="The emulated node boards (watchdogs, fault injection); absent on the robot.", default=None
    )
