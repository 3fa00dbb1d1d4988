from milling_twin.orchestrator.cli import main  # noqa: F401
