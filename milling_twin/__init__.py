"""Milling twin: FMUs of CNC milling co-simulated against recorded machine data."""
__version__ = "0.1.0"
