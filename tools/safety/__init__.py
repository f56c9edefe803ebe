"""Safety verification: the invariants of FAULTS.md as an oracle, the fault rig and the soak."""
