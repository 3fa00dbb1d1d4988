"""SSP 1.0 (System Structure and Parameterization): a scenario exported as an archive other co-simulation tools
open (OMSimulator, libcosim, FMPy, easySSP), and such an archive run as a scenario. ``export.py`` writes it
(``milling-twin export-ssp``), ``importer.py`` reads it back (``milling-twin run twin.ssp``), ``common.py`` holds
what both use. The format and what SSP 1.0 cannot express: docs/ssp.md."""
