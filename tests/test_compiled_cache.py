"""The compiled kernel's cache: a home (or a NUMBA_CACHE_DIR) that cannot be written still starts (the temporary folder,
said in one line), ``NUMBA_CACHE_DIR`` wins, a cold cache is announced before compiling, and the
time numba spends compiling is measured (real numba, real processes)."""

from __future__ import annotations

import os
import subprocess
import sys

import numba

from sb3_marl.common import compiled

SHOW_CACHE = "import os, sb3_marl; print(os.environ['NUMBA_CACHE_DIR'])"


def _python(code: str, **env: str) -> subprocess.CompletedProcess:
    environment = {key: value for key, value in os.environ.items() if key not in ("NUMBA_CACHE_DIR", "MPLCONFIGDIR")}
    return subprocess.run(
        [sys.executable, "-c", code], env={**environment, **env}, capture_output=True, text=True, timeout=300
    )


def test_a_home_that_cannot_be_written_caches_the_kernel_in_the_temporary_folder(tmp_path):
    (tmp_path / "a-file").write_text("")  # a folder below a file can never be made, not even by root
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    done = _python(SHOW_CACHE, XDG_CACHE_HOME=str(tmp_path / "a-file" / "cache"), TMPDIR=str(temporary))
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().startswith(str(temporary / f"sb3-marl-{os.getuid()}" / "numba"))
    assert done.stderr.splitlines() == [
        f"sb3-marl: {tmp_path / 'a-file' / 'cache'} cannot be written; the road kernel is cached in {done.stdout.strip()} "
        "(NUMBA_CACHE_DIR chooses)"
    ]


def test_numba_cache_dir_wins_and_a_writable_home_is_used_silently(tmp_path):
    done = _python(SHOW_CACHE, NUMBA_CACHE_DIR=str(tmp_path / "mine"))
    assert done.stdout.strip() == str(tmp_path / "mine") and done.stderr == ""
    done = _python(SHOW_CACHE, XDG_CACHE_HOME=str(tmp_path / "home"))
    assert done.stdout.strip().startswith(str(tmp_path / "home" / "sb3-marl" / "numba")) and done.stderr == ""


def test_numba_imported_first_caches_in_the_chosen_folder_too(tmp_path):
    """numba reads NUMBA_CACHE_DIR at its own import: imported before sb3_marl (a script's
    ``from numba import njit`` first), it must still cache in the folder of these sources'
    version, never beside the source files (where an edit of a called module runs stale code)."""
    code = "import numba, os, sb3_marl; print(numba.core.config.CACHE_DIR == os.environ['NUMBA_CACHE_DIR'])"
    done = _python(code, XDG_CACHE_HOME=str(tmp_path / "home"))
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "True"


def test_a_numba_cache_dir_that_cannot_be_written_falls_back_in_one_line(tmp_path):
    """Another user's cache folder passed on in the environment (``sudo -E``, a shared profile):
    numba would stop with "no locator available"; the temporary folder is used and said."""
    (tmp_path / "a-file").write_text("")
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    theirs = tmp_path / "a-file" / "numba"
    done = _python(SHOW_CACHE, NUMBA_CACHE_DIR=str(theirs), TMPDIR=str(temporary))
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().startswith(str(temporary / f"sb3-marl-{os.getuid()}" / "numba"))
    assert done.stderr.splitlines() == [
        f"sb3-marl: NUMBA_CACHE_DIR={theirs} cannot be written; the road kernel is cached in {done.stdout.strip()} "
        "(NUMBA_CACHE_DIR chooses)"
    ]


def test_a_cold_cache_is_announced_and_a_filled_one_is_not(tmp_path, monkeypatch, capsys):
    """Per road: the highway's step compiled, the merge's is still announced (they compile apart)."""
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    assert compiled.cache_is_cold()
    compiled.announce_compiling()
    assert capsys.readouterr().err == f"sb3-marl: {compiled.COMPILING.format(folder=tmp_path)}\n"
    (tmp_path / "module").mkdir()
    (tmp_path / "module" / "spawn._grid_spawn-83.py311.nbi").write_bytes(b"")  # as numba names it
    assert not compiled.cache_is_cold()
    compiled.announce_compiling()
    assert capsys.readouterr().err == ""
    assert compiled.cache_is_cold(merge=True)
    compiled.announce_compiling(merge=True)
    assert capsys.readouterr().err == f"sb3-marl: {compiled.COMPILING.format(folder=tmp_path)}\n"


def test_the_time_numba_spends_compiling_is_measured():
    @numba.njit
    def twice(x):
        return 2 * x

    with compiled.compiling() as compile_time:
        assert twice(21) == 42
    first = compile_time.seconds
    with compiled.compiling() as compile_time:
        assert twice(4) == 8  # compiled already
    assert first > 0.01 and compile_time.seconds == 0.0
