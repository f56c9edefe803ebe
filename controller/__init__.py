"""The main controller that runs on the patient's backpack computer (gait FSM, DMP, PI², tick loop)."""

import protocol.compiled  # noqa: F401  (the compiled numerics chosen at import)
