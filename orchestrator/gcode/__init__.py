"""Part programs: reconstruction of programs from recorded runs (reconstruct)."""
