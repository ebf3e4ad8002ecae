"""MkDocs hook (mkdocs.yml ``hooks:``): every committed PNG of ``results/`` is a file of the site at
the same path (``results/final_returns.png``), so a page shows a figure with
``![...](results/final_returns.png)`` and the figures are never copied into ``docs/``."""

from pathlib import Path
from typing import Any

from mkdocs.structure.files import File, Files

RESULTS = Path(__file__).resolve().parent.parent / "results"


def on_files(files: Files, config: Any) -> Files:
    for figure in sorted(RESULTS.rglob("*.png")):
        if not figure.is_symlink():  # only the repository's own files, never a link out of it
            src_uri = figure.relative_to(RESULTS.parent).as_posix()
            files.append(File.generated(config, src_uri, abs_src_path=str(figure)))
    return files
