"""The atomic writer leaves no debris: temporary files of processes that are gone are removed by
the next write into their folder, those of live processes and of other hosts are not (real
processes)."""

from __future__ import annotations

import os
import subprocess
import sys

from sb3_marl.common.files import HOST, write_text


def test_the_next_write_removes_the_partial_files_of_dead_processes_only(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True).stdout
    killed = {
        tmp_path / f".model.{HOST}-{dead.strip()}.partial.zip",  # killed mid-write
        tmp_path / f".evaluations.{dead.strip()}.partial.npz",  # the name before the host was in it
    }
    kept = {
        tmp_path / f".result.{HOST}-{os.getpid()}.partial.json",  # a live process's write in progress
        tmp_path / f".result.another-machine-{dead.strip()}.partial.json",  # another host's (a shared disk)
        tmp_path / "notes.partial.txt",  # not a temporary file of ours
    }
    for path in killed | kept:
        path.write_bytes(b"half")
    write_text(tmp_path / "summary.md", "done\n")
    assert {path for path in killed | kept if path.exists()} == kept
    assert (tmp_path / "summary.md").read_text() == "done\n"
