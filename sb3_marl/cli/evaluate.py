"""``sb3-marl evaluate`` (``enjoy``), ``record-video``, ``plot``, ``summary`` and ``baselines``:
what a trained run does and how it compares."""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

from sb3_marl.algos import ALGO_NAMES
from sb3_marl.cli.common import (
    DEFAULT_ENV,
    MAX_COUNT,
    MAX_EPISODES,
    CommandFailed,
    Deprecated,
    UsageError,
    add_run_selection,
    check_file,
    check_folder,
    find_run_of,
    load_model_of,
    positive,
)
from sb3_marl.common.files import write_text
from sb3_marl.envs import DENSITIES, ENV_IDS, MERGE_ENV_IDS, SCENARIO_IDS, av_counts, make_scenario
from sb3_marl.envs.config import LANE_CHANGE, MERGE, SUPERVISOR_PROTOCOLS


def add_parsers(commands: Any) -> None:
    """Add the evaluation's subcommands to the ``sb3-marl`` parser's ``commands``."""
    for name in ("evaluate", "enjoy"):
        evaluate = commands.add_parser(
            name,
            help="evaluate a trained model on seeded episodes" if name == "evaluate" else "alias of evaluate (rl-zoo's name)",
        )
        add_run_selection(evaluate)
        evaluate.add_argument(
            "--eval-episodes", type=positive(maximum=MAX_EPISODES), default=30, help="episodes (default: 30)"
        )
        evaluate.add_argument("-o", "--output", default=None, help="JSON file (default: <run>/evaluation.json)")
        evaluate.add_argument(
            "--with-baselines",
            nargs="*",
            default=None,
            metavar="POLICY",
            choices=["random", "cruise", "idm-mobil"],
            help="add reference policies on the same seeds to the table: the ones named, or all of "
            "them (random, cruise, idm-mobil) without a name",
        )
        evaluate.set_defaults(handler=evaluate_command)

    plot = commands.add_parser("plot", help="learning-curve PNGs of one or several runs")
    plot.add_argument(
        "--algo", "--algos", dest="algos", nargs="+", default=["ma2c"], choices=ALGO_NAMES, help="learners to plot"
    )
    plot.add_argument("--env", default=DEFAULT_ENV, choices=SCENARIO_IDS, help="scenario id")
    plot.add_argument("-f", "--folder", "--log-folder", dest="folder", default="logs", help="log folder of the runs")
    plot.add_argument("--exp-ids", type=int, nargs="+", default=None, help="runs to plot (default: all)")
    plot.add_argument("-w", "--episode-window", type=positive(), default=100, help="rolling window of training returns")
    plot.add_argument("-o", "--output", default=None, help="folder for the PNGs (default: <folder>/plots)")
    plot.set_defaults(handler=plot_command)

    video = commands.add_parser("record-video", help="mp4 of evaluation episodes, rendered headless")
    add_run_selection(video)
    video.add_argument(
        "--eval-episodes", type=positive(maximum=MAX_COUNT), default=1, help="episodes in the video (default: 1)"
    )
    video.add_argument(
        "--n-episodes", dest="eval_episodes", type=positive(maximum=MAX_COUNT), action=Deprecated, new="--eval-episodes"
    )
    video.add_argument("-o", "--output", default=None, help="mp4 file (default: <run>/videos/<model>.mp4)")
    video.set_defaults(handler=record_video_command)

    summary = commands.add_parser("summary", help="markdown table of the evaluated runs of a log folder")
    summary.add_argument("-f", "--folder", "--log-folder", dest="folder", default="logs", help="log folder of the runs")
    summary.add_argument("-o", "--output", default=None, help="markdown file (default: <folder>/summary.md)")
    summary.set_defaults(handler=summary_command)

    baselines = commands.add_parser("baselines", help="metrics of the reference policies (random, cruise, IDM/MOBIL)")
    baselines.add_argument("--env", default=DEFAULT_ENV, choices=SCENARIO_IDS, help="scenario id")
    baselines.add_argument(
        "--eval-episodes", type=positive(maximum=MAX_EPISODES), default=20, help="episodes per policy, AV count and protocol"
    )
    baselines.add_argument("--seed", type=int, default=0, help="first episode seed")
    baselines.add_argument(
        "--supervisor",
        nargs="+",
        choices=list(SUPERVISOR_PROTOCOLS),
        default=list(SUPERVISOR_PROTOCOLS),
        help="safety supervisor protocols: on (the authors'), off (the policy alone)",
    )
    baselines.add_argument(
        "-o", "--output", type=Path, default=None, help="markdown table, .json beside (default: logs/baselines_<env>.md)"
    )
    # the old spellings, for one release
    baselines.add_argument(
        "--episodes", dest="eval_episodes", type=positive(maximum=MAX_EPISODES), action=Deprecated, new="--eval-episodes"
    )
    baselines.add_argument("--out", dest="output", type=Path, action=Deprecated, new="-o/--output")
    baselines.add_argument("--density", type=int, choices=sorted(DENSITIES), action=Deprecated, new="--env")
    baselines.add_argument("--scenario", choices=[LANE_CHANGE, MERGE], action=Deprecated, new="--env")
    baselines.set_defaults(handler=baselines_command)


def evaluate_command(args: argparse.Namespace) -> int:
    from sb3_marl.evaluation import evaluate_protocols, markdown_table, protocol_rows
    from sb3_marl.runs.experiment import EVAL_SEED_OFFSET

    check_file("-o/--output", args.output)
    run = find_run_of(args)
    model = load_model_of(run, args)
    seed = args.seed + EVAL_SEED_OFFSET
    start = time.perf_counter()
    result = {"model": str(run.model_path), **run.evaluate(model, args.eval_episodes, seed, args.deterministic, progress=True)}
    rows = protocol_rows({"policy": args.algo, "timesteps": model.num_timesteps}, result)
    if args.with_baselines is not None:
        from sb3_marl.evaluation.baselines import BASELINES

        result["baselines"] = {}
        for name, policy_class in BASELINES.items():
            if args.with_baselines and name not in args.with_baselines:
                continue
            baseline = evaluate_protocols(policy_class(), args.env, args.eval_episodes, seed, run.env_config, progress=True)
            result["baselines"][name] = baseline
            rows += protocol_rows({"policy": name, "timesteps": "-"}, baseline)
    heading = (
        f"{args.env}: {args.eval_episodes} episodes, seeds {seed}..{seed + args.eval_episodes - 1}, "
        f"{result['protocol']} (on: the authors' protocol; off: the policy alone); model {run.model_path}"
    )
    table = markdown_table(rows)
    print(heading + "\n")
    print(table)
    output = Path(args.output) if args.output else run.log_path / "evaluation.json"
    write_text(output, json.dumps(result, indent=2))
    write_text(output.with_suffix(".md"), heading + "\n\n" + table + "\n")
    print(f"\nwrote {output} and {output.with_suffix('.md')} ({time.perf_counter() - start:.1f} s)")
    return 0


def record_video_command(args: argparse.Namespace) -> int:
    from sb3_marl.algos.common.policies import model_policy
    from sb3_marl.evaluation.video import record_video
    from sb3_marl.runs.experiment import EVAL_SEED_OFFSET

    run = find_run_of(args)
    model = load_model_of(run, args)
    output = Path(args.output) if args.output else run.log_path / "videos" / f"{run.model_path.stem}.mp4"
    check_file("-o/--output", output)
    try:
        info = record_video(
            model_policy(model, args.deterministic),
            args.env,
            output,
            args.eval_episodes,
            args.seed + EVAL_SEED_OFFSET,
            run.env_config,
        )
    except (OSError, RuntimeError) as error:  # ffmpeg missing, broken or refusing the file
        raise CommandFailed(
            f"could not write the video {output} with ffmpeg ({type(error).__name__}: "
            f"{str(error).strip().splitlines()[-1] if str(error).strip() else error}); check the "
            "ffmpeg that imageio-ffmpeg uses (IMAGEIO_FFMPEG_EXE)."
        ) from None
    print(f"wrote {info['path']}: {info['episodes']} episode(s), {info['frames']} frames at {info['fps']} fps")
    return 0


def plot_command(args: argparse.Namespace) -> int:
    from sb3_marl.evaluation.plotting import plot_runs
    from sb3_marl.runs.folders import run_folders, run_id, run_overrides

    runs = {}
    for algo in args.algos:
        if not run_folders(args.folder, algo, args.env):
            print(f"no runs of {algo} on {args.env} under {args.folder}/: left out of the plots")
        for folder in run_folders(args.folder, algo, args.env):
            if args.exp_ids is None or run_id(folder) in args.exp_ids:
                try:
                    overrides = run_overrides(folder, args.env)
                except ValueError as error:  # an args.yml that is not plain data: named, never read
                    raise UsageError(str(error)) from None
                runs[f"{algo} run {run_id(folder)}" + (f" ({overrides})" if overrides else "")] = folder
    if not runs:
        raise UsageError(f"No runs of {args.algos} on {args.env} under {args.folder}/ (exp ids: {args.exp_ids or 'all'}).")
    output = args.output or os.path.join(args.folder, "plots")
    check_folder("-o/--output", output)
    try:
        written = plot_runs(runs, output, args.episode_window)
    except ValueError as error:
        raise UsageError(str(error)) from None
    for path in written:
        print(f"wrote {path}")
    return 0


def summary_command(args: argparse.Namespace) -> int:
    from sb3_marl.runs.folders import summary_table

    if not os.path.isdir(args.folder):
        raise UsageError(f"-f/--folder: {args.folder!r} is not a folder.")
    try:
        table = summary_table(args.folder)
    except ValueError as error:  # an unreadable (or unsafe) evaluation.json / args.yml: named
        raise UsageError(str(error)) from None
    if table.count("\n") < 2:
        raise UsageError(f"No evaluated run under {args.folder}/ (run `sb3-marl evaluate` on a run first).")
    output = Path(args.output) if args.output else Path(args.folder) / "summary.md"
    check_file("-o/--output", output)
    write_text(output, table + "\n")
    print(table)
    print(f"\nwrote {output}")
    return 0


def baselines_command(args: argparse.Namespace) -> int:
    from sb3_marl.envs.config import with_supervisor
    from sb3_marl.evaluation import markdown_table, run_episodes, summarize
    from sb3_marl.evaluation.baselines import BASELINES

    env_id = args.env
    if args.density is not None or args.scenario is not None:  # the old --density / --scenario
        scenario = args.scenario or LANE_CHANGE
        env_id = (MERGE_ENV_IDS if scenario == MERGE else ENV_IDS)[args.density or 1]
    output = args.output or Path("logs") / f"baselines_{env_id.replace('/', '-')}.md"
    check_file("-o/--output", output)
    rows, results = [], []
    start = time.perf_counter()
    for name, policy_class in BASELINES.items():
        for n_avs in av_counts(env_id):
            for protocol in args.supervisor:
                env = make_scenario(env_id, with_supervisor({"n_avs": n_avs}, protocol))
                summary = summarize(run_episodes(env, policy_class(), args.eval_episodes, seed=args.seed))
                label = {"policy": name, "n_avs": n_avs, "supervisor": protocol}
                results.append({**label, **summary})
                rows.append((label, summary))
    table = (
        f"Scenario {env_id}: {args.eval_episodes} episodes per row, "
        f"seeds {args.seed}..{args.seed + args.eval_episodes - 1}\n\n" + markdown_table(rows)
    )
    print(table)
    write_text(output, table + "\n")
    write_text(output.with_suffix(".json"), json.dumps(results, indent=2))
    print(f"\nwrote {output} and {output.with_suffix('.json')} in {time.perf_counter() - start:.1f} s")
    return 0
