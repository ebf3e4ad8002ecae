"""The compiled (numba) road kernel's cache: where it lives, whether this process compiles, and how
long compiling took.

numba compiles the kernel for the CPU it runs on at the first call of each function and caches the
machine code in ``NUMBA_CACHE_DIR``; a later process loads it in a fraction of a second. The cache
lives in the user's cache folder (``$XDG_CACHE_HOME`` or ``~/.cache``, under ``sb3-marl/numba/``),
one sub-folder per version of the compiled sources; where that folder cannot be written (a service
account, a read-only container) it lives in the temporary folder instead, and ``NUMBA_CACHE_DIR``,
if set, wins over both.
"""

from __future__ import annotations

import os
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

#: What a cold start prints before the first command that steps a road compiles (measured by
#: ``benchmarks/first_run.py``: ``results/speed/first_run.txt``).
COMPILING = "compiling the road kernel for this CPU (first run only, up to a minute on one core; cached in {folder})"


def _writable(folder: str) -> bool:
    """Whether ``folder`` exists or can be made, and a file can be written into it."""
    try:
        os.makedirs(folder, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            return True
    except OSError:
        return False


def choose_cache_folder(digest: str) -> str | None:
    """Set ``NUMBA_CACHE_DIR`` (unless it is set to a folder that can be written) to the user's
    cache folder for the sources of ``digest``, or to the temporary folder where that cannot be
    written; returns a line for the user when it had to fall back, None otherwise."""
    chosen = os.environ.get("NUMBA_CACHE_DIR")
    if chosen and _writable(chosen):
        return None
    home = os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache")
    preferred = chosen or os.path.join(home, "sb3-marl", "numba", digest)
    user = getattr(os, "getuid", lambda: "user")()
    fallback = os.path.join(tempfile.gettempdir(), f"sb3-marl-{user}", "numba", digest)
    unwritable = f"NUMBA_CACHE_DIR={chosen}" if chosen else home
    for folder in (preferred, fallback):
        if _writable(folder):
            _use(folder)
            if folder == preferred:
                return None
            # matplotlib (the figures, the renderer) caches beside it, and would say so in 3 lines
            os.environ.setdefault("MPLCONFIGDIR", os.path.join(os.path.dirname(os.path.dirname(fallback)), "matplotlib"))
            return f"sb3-marl: {unwritable} cannot be written; the road kernel is cached in {folder} (NUMBA_CACHE_DIR chooses)"
    _use(fallback)
    return f"sb3-marl: neither {preferred} nor {fallback} can be written: set NUMBA_CACHE_DIR to a writable folder"


def _use(folder: str) -> None:
    """numba caches in ``folder``, also where it was imported before sb3_marl: it reads
    ``NUMBA_CACHE_DIR`` once, at its import, and without it caches beside each source file, where
    a function's cache is checked only against its own file: an edit of a function it calls would
    then run stale code."""
    os.environ["NUMBA_CACHE_DIR"] = folder
    config = sys.modules.get("numba.core.config")
    if config is not None:
        config.CACHE_DIR = folder  # type: ignore[attr-defined]


def cache_is_cold(merge: bool = False) -> bool:
    """Whether this process will compile the step of the lane change's highway (or, with ``merge``,
    the merge's road): the cache holds none of that road's own functions yet (its spawn, in
    :mod:`sb3_marl.sim.spawn`; the two roads' steps are compiled apart)."""
    folder = Path(os.environ.get("NUMBA_CACHE_DIR", ""))
    spawn = "_merge_spawn" if merge else "_grid_spawn"
    return not folder.is_dir() or next(folder.rglob(f"*.{spawn}-*.nbi"), None) is None


def announce_compiling(merge: bool = False) -> None:
    """One line on stderr before a command compiles its road's step (nothing when it is cached)."""
    if cache_is_cold(merge):
        print("sb3-marl: " + COMPILING.format(folder=os.environ.get("NUMBA_CACHE_DIR")), file=sys.stderr, flush=True)


class CompileTime:
    """Seconds numba spent compiling (or loading from its cache) inside :func:`compiling`."""

    seconds: float = 0.0


@contextmanager
def compiling() -> Iterator[CompileTime]:
    """Measure the time numba spends compiling in the block (nested compilations counted once)."""
    from numba.core.event import TimingListener, install_listener

    measured, listener = CompileTime(), TimingListener()
    try:
        with install_listener("numba:compile", listener):
            yield measured
    finally:
        measured.seconds = listener.duration if listener.done else 0.0
