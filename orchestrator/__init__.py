"""Co-simulation orchestrator of the milling digital twin: scenarios, master, results, report.

Run ``python -m milling_twin.orchestrator run <scenario.toml>``; see ``milling_twin.orchestrator.cli``.
"""
