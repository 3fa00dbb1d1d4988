"""Names that become one component of a path (a run folder, a calibration folder, a study's folder, a case).

A name read from a file (``[scenario] name``, ``[calibration] name``, ``[study] name``, a case id, a file
name given in a spec) is joined to an output folder chosen on the command line; it must name exactly one
entry inside that folder on every platform, so :func:`name_problem` refuses:

* the empty name and names made only of dots (``.`` and ``..`` leave the folder; ``...`` is the same as
  ``..`` on Windows, which strips trailing dots);
* path separators (``/``, ``\\``) and the drive or stream separator ``:`` (an absolute or drive path);
* control characters (U+0000..U+001F, U+007F..U+009F) and the characters Windows refuses in file names
  (``<>"|?*``);
* a trailing space or dot (Windows drops them, so two different names would share a folder);
* Windows' reserved device names (``CON``, ``PRN``, ``AUX``, ``NUL``, ``COM1``-``COM9``, ``LPT1``-``LPT9``,
  also with an extension, in any case).

Callers turn the problem into their own error naming the file and key (``ScenarioError``,
``CalibrationSpecError``, ``StudyError``) or a ``ValueError`` (:func:`check_name`).
"""
from __future__ import annotations

import re

__all__ = ["check_name", "name_problem"]

_FORBIDDEN = set('/\\:<>"|?*')
_RESERVED = re.compile(r"^(con|prn|aux|nul|com[1-9]|lpt[1-9])(\..*)?$", re.IGNORECASE)


def name_problem(name: object) -> str | None:
    """Why ``name`` cannot be one path component (a sentence to follow the name in a message), or None."""
    if not isinstance(name, str):
        return f"expected text, got {type(name).__name__}"
    if not name:
        return "is empty"
    if set(name) == {"."}:
        return "is made of dots only ('.' and '..' name a folder outside the output folder)"
    bad = sorted({c for c in name if c in _FORBIDDEN or ord(c) < 0x20 or 0x7F <= ord(c) <= 0x9F})
    if bad:
        shown = ", ".join(repr(c) for c in bad)
        return f"holds {shown}: a name is one folder or file name, without separators or control characters"
    if name[-1] in " .":
        return "ends with a space or a dot (Windows drops them)"
    if _RESERVED.match(name):
        return "is a device name on Windows"
    return None


def check_name(name: object, where: str) -> str:
    """``name`` when it is one safe path component, else ``ValueError`` naming ``where`` (file and key)."""
    problem = name_problem(name)
    if problem is not None:
        raise ValueError(f"{where}: {name!r} {problem}")
    return name  # type: ignore[return-value]
