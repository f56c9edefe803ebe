"""The AIDER CAN protocol: catalogue (from ``aider.dbc``), codec, end-to-end checks, bus access."""
