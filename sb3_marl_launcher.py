"""The ``sb3-marl`` console script's entry point, outside the package on purpose: it takes SIGINT
and SIGTERM before ``import sb3_marl`` runs (about 2 s: torch, gymnasium, SB3, the compiled
kernel's modules), so a signal at any moment ends with one line and exit 130 / 143, as it does once
a command runs (:class:`sb3_marl.cli.common.StopOnSignals`), instead of a traceback (SIGINT) or a
silent exit (SIGTERM). ``python -m sb3_marl`` imports the package before any code of ours runs."""

from __future__ import annotations

import signal
import sys
from typing import Any

EXIT_CODES = {signal.SIGINT: 130, signal.SIGTERM: 143}


def main() -> int:
    received: list[int] = []

    def stop(signum: int, frame: Any) -> None:
        if not received:
            received.append(signum)
            raise KeyboardInterrupt

    for signum in EXIT_CODES:
        signal.signal(signum, stop)
    try:
        from sb3_marl.cli import main as run_command

        return run_command()
    except KeyboardInterrupt:  # before the command began (or after it ended): it wrote nothing
        name = signal.Signals(received[0] if received else signal.SIGINT)
        print(f"sb3-marl: interrupted ({name.name}) while starting; nothing was written.", file=sys.stderr)
        return EXIT_CODES[name]
    finally:
        for signum in EXIT_CODES:  # the process is ending: a late signal changes nothing
            signal.signal(signum, signal.SIG_IGN)


if __name__ == "__main__":
    sys.exit(main())
