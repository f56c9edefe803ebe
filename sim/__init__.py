"""PyBullet model of the Hybrid Human-Exoskeleton Agent (HHEA), its sensors and the patient."""

import protocol.compiled  # noqa: F401  (the compiled numerics chosen at import)
