"""SIGTERM ends any command as Ctrl-C does: one line naming the signal, exit 143, no traceback and
no file (a real process, a real signal)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

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
