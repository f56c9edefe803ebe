"""Safety verification: the invariants of docs/FAULTS.md as an oracle, the fault rig and the soak."""
