"""SIGTERM ends any command as Ctrl-C does: one line naming the signal, exit 143, no traceback and
no file; so do both while the package is still importing (real processes, real signals)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

SB3_MARL = str(Path(sys.executable).parent / "sb3-marl")


def test_sigterm_of_a_long_command_is_one_line_and_exit_143(tmp_path):
    argv = [SB3_MARL, "baselines", "--eval-episodes", "3000", "-o", str(tmp_path / "b.md")]
    process = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(8)
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 143, err
    lines = [line for line in err.splitlines() if not line.startswith("sb3-marl: compiling")]
    assert lines == [
        "sb3-marl baselines: interrupted (SIGTERM); files it had written are complete (each is written whole), "
        "nothing else was written."
    ]
    assert list(tmp_path.iterdir()) == []


def _catches_sigterm(pid: int) -> bool:
    """Whether process ``pid`` has a handler of its own for SIGTERM (Linux's /proc SigCgt mask)."""
    status = Path(f"/proc/{pid}/status").read_text()
    caught = int(next(line.split()[1] for line in status.splitlines() if line.startswith("SigCgt:")), 16)
    return bool(caught >> (signal.SIGTERM - 1) & 1)


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads the signal mask from Linux's /proc")
@pytest.mark.parametrize(("signum", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_while_the_package_imports_is_one_line(tmp_path, signum, code):
    # the console script's launcher takes both signals before `import sb3_marl` (~2 s): the signal
    # is sent as soon as it has, while the import runs
    argv = [SB3_MARL, "train", "--algo", "ma2c", "-n", "300", "-f", str(tmp_path / "logs")]
    process = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 10
    while not _catches_sigterm(process.pid) and time.monotonic() < deadline:
        time.sleep(0.005)
    process.send_signal(signum)
    _, err = process.communicate(timeout=60)
    assert process.returncode == code, err
    assert err.splitlines() == [f"sb3-marl: interrupted ({signal.Signals(signum).name}) while starting; nothing was written."]
    assert list(tmp_path.iterdir()) == []
