"""The one exception type of the alignment package."""
from __future__ import annotations

__all__ = ["AlignmentError"]


class AlignmentError(ValueError):
    """Invalid input to an alignment, or an alignment that cannot be done; the message names
    the input (file, row, column or argument) and what is wrong with it."""
