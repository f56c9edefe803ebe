"""PyBullet model of the Hybrid Human-Exoskeleton Agent (HHEA), its sensors and the patient."""
