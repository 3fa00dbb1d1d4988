"""Validation of the FMUs against measurements that stay outside the repository (see each module)."""
