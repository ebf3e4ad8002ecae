"""The ``sb3-marl`` command line (also ``python -m sb3_marl``), with rl-zoo's flag names.

    sb3-marl train --algo ma2c --env sb3_marl/LaneChange-density1-v0 -n 100000 -f logs
    sb3-marl evaluate --algo ma2c --env sb3_marl/LaneChange-density1-v0 -f logs   (alias: enjoy)
    sb3-marl plot --algo ma2c mappo --env sb3_marl/LaneChange-density1-v0 -f logs
    sb3-marl record-video --algo ma2c --env sb3_marl/LaneChange-density1-v0 -f logs
    sb3-marl push-to-hub --algo ma2c --env sb3_marl/LaneChange-density1-v0 -f logs -orga ORG [--dry-run PATH]
    sb3-marl load-from-hub --repo-id ORG/NAME -f logs
    sb3-marl baselines                    (reference policies: random, cruise and IDM/MOBIL)
    sb3-marl summary -f logs              (markdown table of the evaluated runs)
    sb3-marl benchmark --grid paper --budget 0.05   (the paper's experiments as Ray Tune trials)
    sb3-marl benchmark status -f logs/benchmark     (where each trial stands)
    sb3-marl benchmark report -f logs/benchmark -o results
    sb3-marl trained-agents               (the committed models; evaluate/enjoy/record-video --trained NAME)
    sb3-marl sweep penetration --trained safe --env sb3_marl/LaneChange-density3-v0   (also: sweep generalisation)

Timesteps (``-n``, ``--eval-freq``, ``--save-freq``) count AV-steps, SB3's timesteps on the
parameter-sharing VecEnv: one step of a scenario copy with N AVs is N timesteps.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys

from sb3_marl import __version__
from sb3_marl.cli import baselines, benchmark, evaluate, hub, sweep, train
from sb3_marl.cli.common import (
    EXIT_INTERRUPTED,
    CommandFailed,
    CommandParser,
    DefaultsHelpFormatter,
    StopOnSignals,
    UsageError,
    os_error_text,
)


def build_parser() -> argparse.ArgumentParser:
    """The ``sb3-marl`` parser: each command group adds its subcommands and their handlers."""
    parser = argparse.ArgumentParser(
        prog="sb3-marl",
        description="Multi-agent RL for cooperative lane changing of CAVs",
        formatter_class=DefaultsHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND", parser_class=CommandParser)
    for group in (train, evaluate, baselines, hub, benchmark, sweep):
        group.add_parsers(commands)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    stop = StopOnSignals()
    try:
        handler = vars(args).pop("handler")  # not an argument: rl-zoo saves the arguments in args.yml
        with stop:
            return handler(args)
    except (UsageError, CommandFailed) as error:
        print(f"sb3-marl {args.command}: error: {error}", file=sys.stderr)
        return 2 if isinstance(error, UsageError) else 1
    except (KeyboardInterrupt, SystemError) as error:  # numba reports Ctrl-C in compiled code as a SystemError
        from sb3_marl.runs.experiment import interrupted_by_user

        if not interrupted_by_user(error):
            raise
        signum = signal.Signals(stop.signal or signal.SIGINT)
        print(
            f"sb3-marl {args.command}: interrupted ({signum.name}); files it had written are complete (each is "
            "written whole), nothing else was written.",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED[signum]
    except BrokenPipeError:  # `sb3-marl ... | head` closed the pipe: stop quietly, as other tools do
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no error when Python flushes at exit
        return 1
    except OSError as error:  # no room, read-only, no permission, ...: files already written are whole
        print(f"sb3-marl {args.command}: error: {os_error_text(error)}.", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
