"""``sb3-marl evaluate`` (``enjoy``), ``record-video``, ``plot``, ``summary`` and ``trained-agents``:
what a trained run does and how it compares."""

from __future__ import annotations

import argparse
import dataclasses
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
    StoreHyperparams,
    UsageError,
    add_refused_flags,
    add_run_selection,
    check_file,
    check_folder,
    check_readable,
    find_run_of,
    load_model_of,
    outputs_of,
    positive,
)
from sb3_marl.common.files import write_text
from sb3_marl.envs import MERGE_ENV_IDS, SCENARIO_IDS, make_scenario


def add_parsers(commands: Any) -> None:
    """Add the evaluation's subcommands to the ``sb3-marl`` parser's ``commands``."""
    for name in ("evaluate", "enjoy"):
        evaluate = commands.add_parser(
            name,
            help="evaluate a trained model on seeded episodes" if name == "evaluate" else "alias of evaluate (rl-zoo's name)",
        )
        add_run_selection(evaluate)
        _add_play_flags(evaluate, default_episodes=30, maximum=MAX_EPISODES)
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
    _add_play_flags(video, default_episodes=1, maximum=MAX_COUNT)
    video.add_argument(
        "--n-episodes", dest="eval_episodes", type=positive(maximum=MAX_COUNT), action=Deprecated, new="--eval-episodes"
    )
    video.add_argument(
        "-o",
        "--output",
        "--output-folder",
        dest="output",
        default=None,
        help="mp4 file, or a folder to write <model>.mp4 into (rl-zoo's -o) (default: <run>/videos/<model>.mp4)",
    )
    video.set_defaults(handler=record_video_command)

    trained = commands.add_parser("trained-agents", help="the committed trained agents (the names --trained takes)")
    trained.add_argument("--algo", default=None, choices=ALGO_NAMES, help="only this learner's")
    trained.add_argument("--env", default=None, choices=SCENARIO_IDS, help="only this scenario's")
    trained.add_argument(
        "-f", "--folder", default=None, help="a benchmark grid folder (default: the repository's results/paper-grid)"
    )
    trained.set_defaults(handler=trained_agents_command)

    summary = commands.add_parser("summary", help="markdown table of the evaluated runs of a log folder")
    summary.add_argument("-f", "--folder", "--log-folder", dest="folder", default="logs", help="log folder of the runs")
    summary.add_argument("-o", "--output", default=None, help="markdown file (default: <folder>/summary.md)")
    summary.set_defaults(handler=summary_command)


#: rl-zoo's enjoy / record_video flags that have no meaning here -> why (refused with that message).
REFUSED_PLAY_FLAGS: dict[tuple[str, ...], str] = {
    ("--n-envs",): "the policy plays one scenario at a time, every AV of it (the AV count cycles over the episodes)",
    ("--norm-reward",): "no model here is trained with VecNormalize: returns are the paper's reward",
    ("--reward-log",): "each episode's return is written to the evaluation's JSON (-o)",
    ("--custom-objects",): "models load as data; --trust-remote-code loads another tool's pickled zip",
    ("--gym-packages",): "the scenarios register themselves when sb3_marl is imported",
}


def _add_play_flags(parser: argparse.ArgumentParser, default_episodes: int, maximum: int) -> None:
    """How long a model plays (episodes, or rl-zoo's ``-n`` timesteps) and rl-zoo's ``enjoy`` /
    ``record_video`` flags: kept with their meaning, accepted where they change nothing here, or
    refused with the reason."""
    length = parser.add_mutually_exclusive_group()
    length.add_argument(
        "--eval-episodes",
        type=positive(maximum=maximum),
        default=default_episodes,
        help=f"episodes (default: {default_episodes})",
    )
    length.add_argument(
        "-n",
        "--n-timesteps",
        type=positive(maximum=maximum * 1_000),
        default=None,
        help="env steps instead of episodes (rl-zoo's -n): whole episodes until this many steps"
        + ("; the video is cut at this many frames" if default_episodes == 1 else ""),
    )
    parser.add_argument(
        "--stochastic",
        dest="deterministic",
        action="store_false",
        default=False,
        help="sampled actions (rl-zoo's flag; the default)",
    )
    parser.add_argument(
        "--env-kwargs",
        nargs="+",
        action=StoreHyperparams,
        default={},
        metavar="KEY:VALUE",
        help="scenario config overrides (merged into the run's env_config), e.g. hdv_politeness:1.0",
    )
    parser.add_argument("--verbose", type=int, default=1, choices=[0, 1], help="0: no progress bars")
    parser.add_argument(
        "--no-render", action="store_true", help="accepted for rl-zoo's commands: nothing is drawn on screen here"
    )
    parser.add_argument("-P", "--progress", action="store_true", help="accepted for rl-zoo's commands: progress bars are on")
    add_refused_flags(parser, REFUSED_PLAY_FLAGS)


def _episodes(args: argparse.Namespace, run: Any) -> int:
    """Episodes to play: ``--eval-episodes``, or ``-n`` env steps in whole episodes of the scenario's length."""
    if args.n_timesteps is None:
        return int(args.eval_episodes)
    env = make_scenario(args.env, run.env_config)
    steps = int(env.config["duration"] * env.config["policy_frequency"])
    return max(1, -(-args.n_timesteps // steps))


def _with_env_kwargs(run: Any, args: argparse.Namespace) -> Any:
    """``run`` with ``--env-kwargs`` merged into its scenario config, checked as ``train`` checks it."""
    if not args.env_kwargs:
        return run
    env_config = {**run.env_config, **args.env_kwargs}
    try:
        make_scenario(args.env, env_config).close()
    except ValueError as error:
        raise UsageError(f"--env-kwargs: {error}") from None
    return dataclasses.replace(run, hyperparams={**run.hyperparams, "env_config": env_config})


def evaluate_command(args: argparse.Namespace) -> int:
    from sb3_marl.algos.common.policies import model_policy
    from sb3_marl.common.compiled import announce_compiling
    from sb3_marl.evaluation import evaluate_protocols, markdown_table, protocol_rows
    from sb3_marl.evaluation.traffic_plots import time_space_diagram
    from sb3_marl.evaluation.trips import human_reference, traffic_table, trips_csv
    from sb3_marl.runs.experiment import EVAL_SEED_OFFSET
    from sb3_marl.runs.folders import run_conf_name

    check_file("-o/--output", args.output)
    run = _with_env_kwargs(find_run_of(args), args)
    model = load_model_of(run, args)
    output = Path(args.output) if args.output else outputs_of(args, run) / "evaluation.json"
    if not args.output:  # the evaluation's files go beside the model: known before the work
        check_folder("-f/--log-folder", str(output.parent))
    announce_compiling(merge=run.env_id in MERGE_ENV_IDS.values())
    seed, episodes, progress = args.seed + EVAL_SEED_OFFSET, _episodes(args, run), args.verbose > 0
    start = time.perf_counter()
    result = {"model": str(run.model_path), **run.evaluate(model, episodes, seed, args.deterministic, progress, traffic=True)}
    try:  # the row's label: "ma2c (ma2c_safe)" for a run of -conf ma2c_safe (args.yml, not needed otherwise)
        recipe = args.trained or run_conf_name(run.log_path, args.env)
    except ValueError:  # an args.yml that is not plain data: never read; `summary` names it
        recipe = ""
    policy = f"{args.algo} ({recipe})" if recipe else args.algo
    rows = protocol_rows({"policy": policy, "timesteps": model.num_timesteps}, result)
    if args.with_baselines is not None:
        from sb3_marl.evaluation.baselines import BASELINES

        result["baselines"] = {}
        for name, policy_class in BASELINES.items():
            if args.with_baselines and name not in args.with_baselines:
                continue
            baseline = evaluate_protocols(policy_class(), args.env, episodes, seed, run.env_config, progress, traffic=True)
            result["baselines"][name] = baseline
            rows += protocol_rows({"policy": name, "timesteps": "-"}, baseline)
    heading = (
        f"{args.env}: {episodes} episodes, seeds {seed}..{seed + episodes - 1}, "
        f"{result['protocol']} (on: the authors' protocol; off: the policy alone); model {run.model_path}"
    )
    table = markdown_table(rows)
    human = human_reference(args.env, episodes, seed, run.env_config)  # the same episodes, every AV an HDV
    result["all_human"] = {"traffic": human.metrics()}
    reference = {"policy": "all human (no AV)", "timesteps": "-", "supervisor": "-"}
    rows.append((reference, {"trips": human.trips(), **result["all_human"]}))
    traffic = "Traffic (docs/traffic.md: every vehicle, AVs and HDVs, over the same episodes):\n\n" + traffic_table(
        [(label, summary["traffic"]) for label, summary in rows]
    )
    print(heading + "\n")
    print(table + "\n\n" + traffic)
    trips = output.with_name(output.stem + "_trips.csv")
    write_text(trips, trips_csv([{**label, **trip} for label, summary in rows for trip in summary.pop("trips")]))
    write_text(output, json.dumps(result, indent=2))
    write_text(output.with_suffix(".md"), heading + "\n\n" + table + "\n\n" + traffic + "\n")
    diagram = time_space_diagram(
        model_policy(model, args.deterministic),
        args.env,
        seed,
        run.env_config,
        output.with_name(output.stem + "_time_space.png"),
        policy,
    )
    print(f"\nwrote {output}, {output.with_suffix('.md')}, the trip records {trips} and {diagram}")
    print(f"({time.perf_counter() - start:.1f} s)")
    return 0


def record_video_command(args: argparse.Namespace) -> int:
    from sb3_marl.algos.common.policies import model_policy
    from sb3_marl.evaluation.video import VideoExtraMissing, imageio_module, record_video
    from sb3_marl.runs.experiment import EVAL_SEED_OFFSET

    try:
        imageio_module()
    except VideoExtraMissing as error:
        raise CommandFailed(str(error)) from None
    run = _with_env_kwargs(find_run_of(args), args)
    model = load_model_of(run, args)
    name = f"{run.model_path.stem}.mp4"
    output = Path(args.output) if args.output else outputs_of(args, run) / "videos" / name
    if output.is_dir() or output.suffix.lower() != ".mp4":  # rl-zoo's -o: a folder for the video
        output = output / name
    check_file("-o/--output", output)
    try:
        info = record_video(
            model_policy(model, args.deterministic),
            args.env,
            output,
            args.eval_episodes,
            args.seed + EVAL_SEED_OFFSET,
            run.env_config,
            n_frames=args.n_timesteps,
            progress=args.verbose > 0,
        )
    except (OSError, RuntimeError) as error:  # ffmpeg missing, broken or refusing the file
        raise CommandFailed(
            f"could not write the video {output} with ffmpeg ({type(error).__name__}: "
            f"{str(error).strip().splitlines()[-1] if str(error).strip() else error}); check the "
            "ffmpeg that imageio-ffmpeg uses (IMAGEIO_FFMPEG_EXE)."
        ) from None
    print(f"wrote {info['path']}: {info['episodes']} episode(s), {info['frames']} frames at {info['fps']} fps")
    return 0


def trained_agents_command(args: argparse.Namespace) -> int:
    from sb3_marl.benchmark.trained_agents import agents_table, grid_of, list_agents

    try:
        grid = grid_of(args.folder)
    except FileNotFoundError as error:
        raise UsageError(f"-f/--folder: {error}") from None
    if args.folder is not None and grid != Path(args.folder):
        raise UsageError(f"-f/--folder: {args.folder!r} is not a benchmark grid folder (it has no trials/).")
    rows = list_agents(grid, args.algo, args.env)
    if not rows:
        raise UsageError(f"No finished trial of {args.algo or 'any learner'} on {args.env or 'any scenario'} in {grid}.")
    print(
        f"Trained agents in {grid} (final evaluation of each seed: 30 episodes, seeds 10000..10029, sampled "
        "actions; mean ± std over seeds):\n"
    )
    print(agents_table(rows))
    print("\nUse one: sb3-marl evaluate --algo ALGO --env ENV --trained NAME (also enjoy, record-video, push-to-hub)")
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
    check_readable("-f/--folder", args.folder)
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
