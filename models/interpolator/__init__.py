"""Interpolator: the model definition and the Python reference of the FMU's C code (``fmus/interpolator/``).

Step 1 of a split into one module per C file: the former ``models/interpolator.py`` lives in ``engine.py``
for now; every name it defined stays importable from here.
"""
from milling_twin.models.interpolator.engine import *  # noqa: F401,F403
