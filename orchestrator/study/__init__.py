"""Studies: many runs of one scenario (grids, lists, samples, Monte Carlo) dispatched through one executor."""
