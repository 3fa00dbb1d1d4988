"""The C compiler as casadi's just-in-time compilation calls it, with a cache of the objects it makes.

    python compile_cache.py CACHE_DIR COMPILER ARGUMENT...

casadi's "shell" compiler runs ``COMPILER FLAGS -fPIC -c SOURCE.c -o OBJECT.o`` and then links the object into a
shared library. The same model generates the same C source every time, so a compile step whose source, arguments
(the temporary names aside) and compiler are those of an earlier one copies that object instead of compiling it
again: 0.01 s instead of seconds for the slot-forces model. Every other call (the link) runs the compiler as it is.

The objects are kept in CACHE_DIR under the SHA-256 of what made them, written beside their name and renamed into
place, so a killed compile or two processes compiling the same source at once never leave a partial object.

A script of the standard library alone, run by path in a fresh interpreter (``python -I``): it imports nothing of
milling_twin, so it starts in tens of milliseconds.
"""
from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path


def compile_key(compiler: str, arguments: list[str], source: Path, output: str) -> str:
    """The SHA-256 of the compiler (its path, size and time), the arguments but the source's and the object's
    temporary names, and the source's bytes."""
    resolved = shutil.which(compiler) or compiler
    try:
        stat = os.stat(resolved)
        identity = f"{resolved}\0{stat.st_size}\0{stat.st_mtime_ns}"
    except OSError:
        identity = resolved
    digest = hashlib.sha256(identity.encode())
    for argument in arguments:
        if argument not in (str(source), output):
            digest.update(b"\0" + argument.encode())
    digest.update(b"\0\0" + source.read_bytes())
    return digest.hexdigest()


def cached_compile(cache: Path, compiler: str, arguments: list[str]) -> int:
    """Run ``compiler arguments`` through the cache (module text); the compiler's exit status."""
    sources = [a for a in arguments if a.endswith(".c")]
    if "-c" not in arguments or "-o" not in arguments or len(sources) != 1:
        return subprocess.call([compiler, *arguments])
    output = arguments[arguments.index("-o") + 1]
    key = compile_key(compiler, arguments, Path(sources[0]), output)
    cached = cache / f"{key}.o"
    if cached.is_file():
        shutil.copyfile(cached, output)
        return 0
    status = subprocess.call([compiler, *arguments])
    if status == 0:
        partial = None
        try:
            cache.mkdir(parents=True, exist_ok=True)
            handle, partial = tempfile.mkstemp(dir=cache, prefix=f".{key}.")
            os.close(handle)
            shutil.copyfile(output, partial)
            os.replace(partial, cached)
        except OSError as error:  # a cache that cannot be written costs time, not the compilation
            print(f"compile_cache: not cached in {cache}: {error}", file=sys.stderr)
            if partial is not None and os.path.exists(partial):
                os.unlink(partial)
    return status


if __name__ == "__main__":
    if len(sys.argv) < 3:
        sys.exit("usage: compile_cache.py CACHE_DIR COMPILER ARGUMENT...")
    sys.exit(cached_compile(Path(sys.argv[1]), sys.argv[2], sys.argv[3:]))
