"""Co-simulation orchestrator of the milling digital twin: scenarios, master, results, report.

Run ``milling-twin run <scenario.toml>``; the command is :mod:`milling_twin.cli`, the Python API :mod:`milling_twin.api`.
"""
