"""``aider-exo trace``: record, decode, inspect, plot, replay and re-simulate CAN traces.

Everything about frames (IDs, senders, signals, units, CRC seeds, periods) comes from the DBC
through :mod:`protocol.catalog`; decoding and the CRC and alive-counter checks are the project's
own :class:`protocol.e2e.Receiver`; timing goes through :mod:`protocol.clock`. See docs/TRACE.md.
"""

from config.errors import AiderError


class TraceError(AiderError):
    """A trace cannot be read, written, replayed or re-simulated; the message says why."""
