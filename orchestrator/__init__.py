"""Co-simulation orchestrator of the milling digital twin: scenarios, master, results, report.

Run ``python -m orchestrator run <scenario.toml>``; see ``orchestrator.cli``.
"""
