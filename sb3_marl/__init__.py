"""sb3-marl: multi-agent RL for cooperative lane changing of AVs, on Stable-Baselines3."""

import hashlib
import os
import sys
from pathlib import Path


def _compiled_sources_digest() -> str:
    """A digest of every module with compiled (numba) code: numba re-checks only a function's own
    file before reusing its cache, not those of the functions it calls, so a cache folder per
    version of the sources keeps an edit of one module from running stale code of another."""
    root, digest = Path(__file__).parent, hashlib.sha256()
    for path in sorted([*root.glob("sim/*.py"), *root.glob("safety/*.py"), *root.glob("envs/*.py")]):
        digest.update(path.name.encode() + path.read_bytes())
    return digest.hexdigest()[:16]


# numba caches the compiled road kernel in the user's cache folder, not beside the installed
# modules (where `pip uninstall` would leave it behind), or in the temporary folder where that
# cannot be written; NUMBA_CACHE_DIR, if set, wins
from sb3_marl.common.compiled import choose_cache_folder  # noqa: E402

_fallback = choose_cache_folder(_compiled_sources_digest())
if _fallback:
    print(_fallback, file=sys.stderr)

# Intel MKL (torch's matrix products on x86-64) picks its kernels by CPU generation, and an
# AVX-512 kernel sums in another order than an AVX2 one: a learner's trajectory then drifts apart
# from machine to machine. MKL's conditional numerical reproducibility pins the AVX2 kernels on
# every CPU that has them (read at MKL's first call, so it holds when sb3_marl is imported before
# any matrix product); with one torch thread (the CLI's default) the same seed then learns the
# same parameters on any such machine. MKL_CBWR, if set, wins (AUTO: MKL's fastest kernels).
os.environ.setdefault("MKL_CBWR", "AVX2")

from sb3_marl import envs  # noqa: E402, F401  (registers the gymnasium ids)

__version__ = "0.1.0"
