"""Files written so that a crash or an interrupt never leaves a half-written one."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np


@contextmanager
def replaced_atomically(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (``.<stem>.partial<suffix>``) to write to.

    When the block ends normally, the temporary file replaces ``path`` in one rename. When it
    raises (an error, Ctrl-C, SIGTERM turned into KeyboardInterrupt), the temporary file is
    removed and ``path`` keeps its previous content.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.stem}.partial{path.suffix}")
    try:
        yield temporary
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise


def read_evaluations(path: str | Path) -> dict[str, Any]:
    """The arrays of an ``evaluations.npz``; a ValueError naming the file if it is unreadable
    (truncated, not an npz, pickled objects: never unpickled)."""
    try:
        with np.load(path, allow_pickle=False) as log:
            return {key: log[key] for key in log.files}
    except Exception as error:  # zipfile.BadZipFile, OSError, ValueError, EOFError alike
        raise ValueError(f"{path} is not a readable evaluations.npz ({type(error).__name__}: {error}).") from None
