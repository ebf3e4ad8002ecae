"""What the command groups share: errors, the checks of flags and paths, argument types, the
help formatter, finding a run and loading its model."""

from __future__ import annotations

import argparse
import errno
import math
import os
import signal
import sys
import tempfile
from pathlib import Path
from typing import Any

from sb3_marl.algos import ALGO_NAMES
from sb3_marl.envs import ENV_IDS, SCENARIO_IDS

DEFAULT_ENV = ENV_IDS[1]


EXIT_INTERRUPTED = {signal.SIGINT: 130, signal.SIGTERM: 143}


class StopOnSignals:
    """While active, SIGINT and SIGTERM raise KeyboardInterrupt (the first one; ``signal`` records
    which), so a command stops where Python is and its atomic writes and saves run as for Ctrl-C."""

    def __init__(self) -> None:
        self.signal: int | None = None

    def __enter__(self) -> StopOnSignals:
        self._previous = {sig: signal.signal(sig, self._handle) for sig in EXIT_INTERRUPTED}
        return self

    def _handle(self, signum: int, frame: Any) -> None:
        if self.signal is None:
            self.signal = signum
            raise KeyboardInterrupt

    def __exit__(self, *exc: Any) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


class StoreHyperparams(argparse.Action):
    """rl-zoo's ``-params key:value ...``: each value is a literal, never evaluated as code
    (:func:`sb3_marl.common.literals.parse_literal`: ``n_steps:20``, ``env_config:"dict(comfort=False)"``,
    ``policy_kwargs:"dict(activation_fn=nn.Tanh)"``); a bare word stays a string
    (``reward_mode:global``); anything else (a call, an operator) exits 2 naming the key."""

    def __call__(
        self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any, option_string: Any = None
    ) -> None:
        from sb3_marl.common.literals import parse_literal

        parsed = {}
        for item in values:
            key, sep, expression = item.partition(":")
            if not sep or not key:
                parser.error(f"argument {option_string}: expected key:value, got {item!r}")
            try:
                parsed[key] = parse_literal(expression, key)
            except ValueError as error:
                parser.error(f"argument {option_string}: {error}")
        setattr(namespace, self.dest, parsed)


class Refused(argparse.Action):
    """An rl-zoo flag without a meaning here: a usage error that says why (``reason``)."""

    def __init__(self, *args: Any, reason: str, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.reason = reason

    def __call__(self, parser: argparse.ArgumentParser, namespace: Any, values: Any, option_string: Any = None) -> None:
        parser.error(f"{option_string} (rl-zoo's) has no meaning here: {self.reason}.")


def add_refused_flags(parser: argparse.ArgumentParser, refused: dict[tuple[str, ...], str]) -> None:
    """rl-zoo's flags -> why they have no meaning here: each refused with its reason, hidden from ``--help``."""
    for flags, reason in refused.items():
        parser.add_argument(*flags, nargs="*", action=Refused, reason=reason, default=None, help=argparse.SUPPRESS)


class Deprecated(argparse.Action):
    """An old spelling of a flag, kept (hidden) for one release: it sets the new flag's value and
    says, on stderr, which name to use instead.

    :param new: the flag's current name
    """

    def __init__(self, option_strings: list[str], dest: str, new: str, **kwargs: Any) -> None:
        super().__init__(option_strings, dest, help=argparse.SUPPRESS, **kwargs)
        self.new = new

    def __call__(self, parser: argparse.ArgumentParser, namespace: Any, values: Any, option_string: Any = None) -> None:
        print(f"{option_string} is deprecated and goes in the next release: use {self.new}.", file=sys.stderr)
        setattr(namespace, self.dest, values)


def positive(kind: type = int, maximum: float | None = None, minimum: int = 1) -> Any:
    """A parser of a finite ``kind`` value in [``minimum``, ``maximum``] (nan and inf refused)."""

    def parse(text: str) -> Any:
        value = kind(text)
        if not math.isfinite(value) or value < minimum or (maximum is not None and value > maximum):
            bound = "" if maximum is None else f" and <= {maximum:,}"
            raise argparse.ArgumentTypeError(f"expected a finite value >= {minimum}{bound}, got {text}")
        return value

    return parse


def positive_or_minus_one(expected: str) -> Any:
    """A parser of an integer >= 1, or -1 with rl-zoo's meaning (``expected`` says which); 0 and
    other values are refused with ``expected`` in the message."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = 0
        if value != -1 and value < 1:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return value

    return parse


#: Upper bounds of the sizes that allocate: scenario copies (each an env), episodes, seeds, trials.
MAX_COPIES, MAX_EPISODES, MAX_COUNT = 256, 100_000, 10_000


#: A period in AV-steps (0 is refused rather than silently meaning never), and a count or the default.
every = positive_or_minus_one("an integer >= 1 (AV-steps) or -1 (never)")


positive_or_default = positive_or_minus_one("an integer >= 1 or -1 (the default)")


def add_num_threads(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--num-threads",
        type=positive_or_default,
        default=1,
        help="torch threads (default: 1, fastest for these small networks); -1: torch's default",
    )


def set_num_threads(num_threads: int) -> None:
    """``--num-threads``: torch's intra-op threads (0 or less: torch's default)."""
    import torch

    if num_threads > 0:
        torch.set_num_threads(num_threads)


def check_device(device: str) -> None:
    """``--device``: auto, or a torch device this machine has."""
    import torch

    if device == "auto":
        return
    try:
        parsed = torch.device(device)
    except (RuntimeError, ValueError):
        raise UsageError(f"--device: invalid device {device!r}: expected auto, cpu, cuda or cuda:<index>.") from None
    if parsed.type == "cuda" and not torch.cuda.is_available():
        raise UsageError(f"--device: {device!r} asked for, but this machine has no CUDA GPU: use auto or cpu.")


def os_error_text(error: OSError) -> str:
    """What an OS error means for the user, in one line: the path (its folder, for the temporary
    file of an atomic write) and what to do."""
    from sb3_marl.common.files import PARTIAL

    path = error.filename or error.filename2
    if path is not None and PARTIAL.match(os.path.basename(str(path))):
        path = os.path.dirname(str(path)) or "."
    where = repr(str(path)) if path is not None else "a file"
    room = "free some space (or write elsewhere), then run the command again"
    advice = {
        errno.ENOSPC: f"no space left on the device of {where}: {room}",
        errno.EDQUOT: f"the disk quota of {where} is used up: {room}",
        errno.EFBIG: f"a file in {where} grew beyond what this process may write (ulimit -f, or the file system): {room}",
        errno.EROFS: f"{where} is on a read-only file system: choose a writable folder",
        errno.EACCES: f"no permission for {where}: choose a folder you may write (and read), or change its permissions",
        errno.EPERM: f"no permission for {where}: choose a folder you may write (and read), or change its permissions",
        errno.ENOTDIR: f"{where}: a part of this path is a file, not a folder",
        errno.EISDIR: f"{where} is a folder where a file was expected",
        errno.ENOENT: f"{where} does not exist (was it removed while the command ran?)",
    }
    return advice.get(error.errno or 0, f"{where}: {error.strerror or error}")


def check_folder(flag: str, path: str | None) -> None:
    """A folder the command may write into: not a file, no over-long name, and its nearest existing
    folder writable (checked before anything is created)."""
    if not path:
        return
    try:
        path.encode("utf-8")
    except UnicodeEncodeError:
        raise UsageError(f"{flag}: {path!r} is not a valid UTF-8 path (the logs and configs name it).") from None
    try:
        _check_folder(flag, path)
    except OSError as error:  # e.g. a parent folder the user may not enter
        raise UsageError(f"{flag}: {path!r} cannot be used: {os_error_text(error)}.") from None


def _check_folder(flag: str, path: str) -> None:
    if os.path.exists(path) and not os.path.isdir(path):
        raise UsageError(f"{flag}: {path!r} is a file, expected a folder.")
    too_long = [part for part in Path(path).parts if len(os.fsencode(part)) > 255]
    if too_long or len(os.fsencode(os.path.abspath(path))) > 4000:
        raise UsageError(f"{flag}: {path!r} is too long a path (at most 255 bytes per folder name).")
    existing = Path(os.path.abspath(path))
    while not existing.exists():
        existing = existing.parent
    if not os.access(existing, os.W_OK | os.X_OK):
        raise UsageError(f"{flag}: {path!r} cannot be written: {str(existing)!r} is not writable.")
    try:  # a real folder can be made there (not so in /proc, on a read-only mount, ...): probe and remove
        os.rmdir(tempfile.mkdtemp(prefix=".sb3-marl-probe-", dir=existing))
    except OSError as error:
        raise UsageError(
            f"{flag}: {path!r} cannot be written: no folder can be made in {str(existing)!r} ({error.strerror})."
        ) from None


def check_readable(flag: str, path: str | Path) -> None:
    """A folder the command reads: a usage error naming it if the user may not list or enter it
    (another user's private folder), where the command would find nothing in it and say so."""
    if os.path.isdir(path) and not os.access(path, os.R_OK | os.X_OK):
        error = PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(path))
        raise UsageError(f"{flag}: {str(path)!r} cannot be read: {os_error_text(error)}.")


def check_file(flag: str, path: str | Path | None) -> None:
    """A file the command will write (atomically, through a temporary file beside it): not a folder
    or a device, and its folder writable (checked before the work)."""
    if not path:
        return
    if os.path.isdir(path):
        raise UsageError(f"{flag}: {str(path)!r} is a folder, expected a file name.")
    if os.path.exists(path) and not os.path.isfile(path):
        raise UsageError(f"{flag}: {str(path)!r} is not a regular file (a device or a pipe): give a file name.")
    check_folder(flag, os.path.dirname(os.path.abspath(path)))


#: Seeds numpy and the scenario accept: 0 <= seed < 2**32 (episode seeds add 10,000 for evaluation).
MAX_SEED = 2**32 - 1 - 100_000


def check_seed(seed: int) -> None:
    if not 0 <= seed <= MAX_SEED:
        raise UsageError(f"--seed: invalid seed {seed}: expected an integer in [0, {MAX_SEED}].")


def add_run_selection(parser: argparse.ArgumentParser) -> None:
    """rl-zoo ``enjoy``'s flags to pick a trained model."""
    parser.add_argument("--algo", default="ma2c", choices=ALGO_NAMES, help="learner (default: ma2c)")
    parser.add_argument("--env", default=DEFAULT_ENV, choices=SCENARIO_IDS, help="scenario id")
    parser.add_argument("-f", "--folder", "--log-folder", dest="folder", default="logs", help="log folder (default: logs)")
    parser.add_argument("--exp-id", type=int, default=0, help="run id; 0 = latest (default)")
    parser.add_argument(
        "--trained",
        metavar="NAME",
        default=None,
        help="a trained agent by name (paper, safe, or a grid variant; `sb3-marl trained-agents` lists them) "
        "from the grid folder -f or the repository's results/paper-grid (a grid folder as -f alone: paper); "
        "what the command writes goes to <-f>/trained-agents/ (logs/ for a grid)",
    )
    picked = parser.add_mutually_exclusive_group()
    picked.add_argument("--load-best", action="store_true", help="load best_model.zip")
    picked.add_argument("--load-checkpoint", type=int, metavar="STEPS", help="load rl_model_<STEPS>_steps.zip")
    picked.add_argument("--load-last-checkpoint", action="store_true", help="load the latest checkpoint")
    parser.add_argument("--seed", type=int, default=0, help="episode seeds start at seed + 10000 (default: 0)")
    parser.add_argument(
        "--deterministic",
        action="store_true",
        help="argmax actions (default: sampled from the policy, the authors' evaluation protocol)",
    )
    parser.add_argument("--device", default="auto", help="torch device (default: auto)")
    add_trust_remote_code(parser)
    add_num_threads(parser)


def add_trust_remote_code(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--trust-remote-code",
        action="store_true",
        help="load a model zip from another tool that needs unpickling (it can run code: only for "
        "files you trust); default: models are read as data and such a zip is refused",
    )


class CommandParser(argparse.ArgumentParser):
    """A subcommand's parser, showing defaults in its ``--help``."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", DefaultsHelpFormatter)
        super().__init__(*args, **kwargs)


class DefaultsHelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """argparse's defaults in ``--help`` (as rl-zoo users expect), unless the help already says
    what the default is or there is none to show."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        if (
            "default" in text.lower()
            or action.default is None
            or action.default is False
            or action.default == argparse.SUPPRESS
        ):
            return text
        return super()._get_help_string(action)


def find_run_of(args: argparse.Namespace) -> Any:
    """The run ``--algo``/``--env``/``--exp-id`` of ``-f``, or the trained agent ``--trained``."""
    from sb3_marl.benchmark.trained_agents import grid_of, is_grid, trained_agent
    from sb3_marl.runs.folders import find_run

    check_seed(args.seed)
    folder = args.folder
    if args.trained is None and is_grid(folder):  # rl-zoo's `-f rl-trained-agents/`: the paper's agent of a grid
        args.trained = "paper"
    try:
        if args.trained:
            folder = trained_agent(grid_of(args.folder), args.algo, args.env, args.trained)
        return find_run(
            folder, args.algo, args.env, args.exp_id, args.load_best, args.load_checkpoint, args.load_last_checkpoint
        )
    except (FileNotFoundError, ValueError) as error:
        raise UsageError(f"--trained: {error}" if args.trained else str(error)) from None


def outputs_of(args: argparse.Namespace, run: Any) -> Path:
    """Where a command writes what it makes of ``run``: the run's folder, or for a trained agent
    (never written into) ``<-f>/trained-agents/<its trial>/`` (``logs/`` when ``-f`` is the grid)."""
    from sb3_marl.benchmark.trained_agents import is_grid

    if not args.trained:
        return Path(run.log_path)
    trial = Path(run.log_path).parent.parent.name
    return Path("logs" if is_grid(args.folder) else args.folder) / "trained-agents" / trial


def load_model_of(run: Any, args: argparse.Namespace) -> Any:
    """The run's model on ``--device`` with ``--num-threads``; a usage error naming a bad file."""
    check_device(args.device)
    set_num_threads(args.num_threads)
    try:
        return run.load_model(args.device, args.trust_remote_code)
    except ValueError as error:
        raise UsageError(str(error)) from None


class UsageError(Exception):
    """Bad input found before any work: printed as ``sb3-marl <command>: error: ...``, exit code 2."""


class CommandFailed(Exception):
    """The work could not be done (e.g. no Hub token, network error): printed like a UsageError, exit code 1."""
