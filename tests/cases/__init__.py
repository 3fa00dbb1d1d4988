"""Generated test and benchmark cases: synthetic recordings and parts with known truth (alignment), the
synthetic calibration cases and the recovery study. Only tests and tests/benchmarks use them; the package's
commands never do."""
