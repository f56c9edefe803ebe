"""The AIDER CAN protocol: catalogue (from ``aider.dbc``), codec, end-to-end checks, bus access."""

from protocol import compiled  # noqa: F401  (the compiled numerics chosen at import)
