"""Errors of the protocol layer (all :class:`config.AiderError`, printed as one line by the CLI)."""

from __future__ import annotations

from config.errors import AiderError


class ProtocolError(AiderError):
    """The DBC breaks one of the protocol's rules, or a message name is unknown."""


class EncodeError(ProtocolError):
    """A value cannot be put on the bus: not finite, out of its range, or not an enumerated value."""


class BusUnavailableError(AiderError):
    """The configured CAN bus cannot be opened; the message says how to fix it."""
