"""``python -m milling_twin`` is the ``milling-twin`` command."""
import sys

from milling_twin.cli import main

sys.exit(main())
