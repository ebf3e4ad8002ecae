"""``sb3-marl sweep``: trained agents evaluated across conditions (``generalisation``: every
scenario id and the HDVs' politeness; ``penetration``: the share of AVs in a fixed number of
vehicles), with a progress bar, tables and a figure."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from sb3_marl.algos import ALGO_NAMES
from sb3_marl.cli.common import DEFAULT_ENV, MAX_COUNT, MAX_EPISODES, UsageError, check_folder, positive, set_num_threads
from sb3_marl.envs import SCENARIO_IDS

#: The most vehicles a sweep puts on the road.
MAX_VEHICLES = 40


def add_parsers(commands: Any) -> None:
    """Add the sweep's subcommands to the ``sb3-marl`` parser's ``commands``."""
    sweep = commands.add_parser("sweep", help="trained agents across conditions: `sweep generalisation`, `sweep penetration`")
    kinds = sweep.add_subparsers(dest="sweep", required=True, metavar="SWEEP")
    matrix = kinds.add_parser(
        "generalisation",
        help="trained agents on every scenario id and HDV politeness: return and collision rate alone",
        formatter_class=sweep.formatter_class,
    )
    matrix.add_argument("--algo", default="ma2c", choices=ALGO_NAMES, help="learner (default: ma2c)")
    matrix.add_argument(
        "--trained", nargs="+", default=["paper"], metavar="NAME", help="trained agents (default: paper; see trained-agents)"
    )
    matrix.add_argument("-f", "--folder", default=None, help="a grid folder (default: the repository's results/paper-grid)")
    matrix.add_argument("--seeds", type=positive(maximum=MAX_COUNT), default=3, help="training seeds per agent (default: 3)")
    matrix.add_argument(
        "--eval-episodes",
        type=positive(maximum=MAX_EPISODES),
        default=10,
        help="held-out episodes per seed and condition (default: 10)",
    )
    matrix.add_argument(
        "--politeness", type=float, nargs="+", default=[0.0, 0.5, 1.0], help="HDV MOBIL politeness values in [0, 1]"
    )
    matrix.add_argument(
        "--styles",
        nargs="*",
        default=["timid", "aggressive"],
        choices=["timid", "aggressive"],
        help="HDV IDM styles besides normal",
    )
    matrix.add_argument("-o", "--output", default="logs/generalisation", help="folder of the tables and figure")
    matrix.set_defaults(handler=generalisation_command)

    sweep_ = kinds.add_parser(
        "penetration",
        help="a fixed number of vehicles with a growing share of AVs: a trained agent and the rule driver",
        formatter_class=sweep.formatter_class,
    )
    sweep_.add_argument("--algo", default="ma2c", choices=ALGO_NAMES, help="learner (default: ma2c)")
    sweep_.add_argument("--env", default=DEFAULT_ENV, choices=SCENARIO_IDS, help="scenario id")
    sweep_.add_argument("--trained", default="paper", metavar="NAME", help="the trained agent (seed 0; default: paper)")
    sweep_.add_argument("-f", "--folder", default=None, help="a grid folder (default: the repository's results/paper-grid)")
    sweep_.add_argument(
        "--vehicles",
        type=positive(maximum=MAX_VEHICLES),
        default=None,
        help="vehicles on the road (default: the density's most)",
    )
    sweep_.add_argument("--shares", type=int, nargs="+", default=[0, 25, 50, 75, 100], help="AV shares [%%] in [0, 100]")
    sweep_.add_argument(
        "--eval-episodes", type=positive(maximum=MAX_EPISODES), default=30, help="held-out episodes per share (default: 30)"
    )
    sweep_.add_argument("-o", "--output", default="logs/penetration", help="folder of the table and figure")
    sweep_.set_defaults(handler=penetration_command)


def generalisation_command(args: argparse.Namespace) -> int:
    from sb3_marl.benchmark.generalisation import generalisation_matrix, matrix_table, plot_matrix
    from sb3_marl.benchmark.trained_agents import grid_of

    _check(args, all(0 <= p <= 1 for p in args.politeness), f"--politeness: {args.politeness}: expected values in [0, 1].")
    try:
        result = generalisation_matrix(
            grid_of(args.folder), args.algo, args.trained, args.seeds, args.eval_episodes, args.politeness, styles=args.styles
        )
    except FileNotFoundError as error:
        raise UsageError(f"--trained: {error}") from None
    out = Path(args.output)
    heading = (
        f"{args.algo} {', '.join(args.trained)}: {args.seeds} training seed(s), {args.eval_episodes} held-out episodes "
        f"each (seeds {result['episode_seeds'][0]}..{result['episode_seeds'][1]}), sampled actions; columns: the "
        "evaluated scenario and HDV politeness p or IDM style (training: p=0, normal)"
    )
    tables = (
        f"{heading}\n\nReturn with the supervisor (mean over seeds):\n\n{matrix_table(result, 'return_mean', '.2f')}\n\n"
        f"Collision rate alone (supervisor off, pooled over seeds):\n\n{matrix_table(result, 'collision_rate_alone', '.3f')}\n"
    )
    return _write(out / "generalisation", result, tables, plot_matrix)


def penetration_command(args: argparse.Namespace) -> int:
    from sb3_marl.algos.common.policies import model_policy
    from sb3_marl.benchmark.generalisation import HELD_OUT_SEED
    from sb3_marl.benchmark.penetration import densest_mix, penetration_sweep, plot_sweep, sweep_table
    from sb3_marl.benchmark.trained_agents import grid_of, trained_agent
    from sb3_marl.evaluation.baselines import IDMMobilPolicy
    from sb3_marl.runs.folders import find_run

    _check(
        args, all(0 <= share <= 100 for share in args.shares), f"--shares: {args.shares}: expected percentages in [0, 100]."
    )
    try:
        run = find_run(trained_agent(grid_of(args.folder), args.algo, args.env, args.trained), args.algo, args.env)
    except (FileNotFoundError, ValueError) as error:
        raise UsageError(f"--trained: {error}") from None
    vehicles = args.vehicles or densest_mix(args.env)
    policies: dict[str, tuple[Any, dict[str, Any]]] = {
        f"{args.algo} ({args.trained})": (model_policy(run.load_model("cpu")), run.env_config),
        "idm-mobil": (IDMMobilPolicy(), {}),
    }
    try:
        result = penetration_sweep(policies, args.env, vehicles, args.eval_episodes, HELD_OUT_SEED, args.shares)
    except ValueError as error:  # a mix that does not fit the road: the config's message
        raise UsageError(f"--vehicles / --shares: {error}") from None
    out = Path(args.output)
    first, last = result["episode_seeds"]
    table = (
        f"{args.env}: {vehicles} vehicles, {args.eval_episodes} held-out episodes per share (seeds {first}..{last}), "
        f"sampled actions; docs/traffic.md\n\n{sweep_table(result)}\n"
    )
    return _write(out / "penetration", result, table, plot_sweep)


def _check(args: argparse.Namespace, valid: bool, message: str) -> None:
    """A sweep's checks before any work: its values (``message`` unless ``valid``), the output folder."""
    if not valid:
        raise UsageError(message)
    check_folder("-o/--output", args.output)
    set_num_threads(1)


def _write(stem: Path, result: dict[str, Any], text: str, plot: Any) -> int:
    """Print the sweep's ``text``; write it (``<stem>.md``), its ``result`` (``.json``) and ``plot``'s figure (``.png``)."""
    from sb3_marl.common.files import write_text

    print(text)
    write_text(stem.with_suffix(".json"), json.dumps(result, indent=2))
    write_text(stem.with_suffix(".md"), text)
    print(f"wrote {stem.with_suffix('.json')}, {stem.with_suffix('.md')} and {plot(result, stem.with_suffix('.png'))}")
    return 0
