"""Build helpers of the distribution (not installed): what the wheel and the FMU release tarball contain.

``setup.py`` uses :mod:`buildtools.wheel_files` while the wheel is built; ``make release`` runs
:mod:`buildtools.release`. docs/packaging.md.
"""
