"""``sb3-marl baselines``: the reference policies (random, cruise, IDM/MOBIL) on a scenario, on the
episodes ``evaluate --with-baselines`` plays and for each AV count."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

from sb3_marl.cli.common import DEFAULT_ENV, MAX_EPISODES, Deprecated, check_file, positive
from sb3_marl.common.files import write_text
from sb3_marl.envs import DENSITIES, ENV_IDS, MERGE_ENV_IDS, SCENARIO_IDS, av_counts, make_scenario
from sb3_marl.envs.config import LANE_CHANGE, MERGE, SUPERVISOR_PROTOCOLS


def add_parsers(commands: Any) -> None:
    """Add ``baselines`` to the ``sb3-marl`` parser's ``commands``."""
    baselines = commands.add_parser("baselines", help="metrics of the reference policies (random, cruise, IDM/MOBIL)")
    baselines.add_argument("--env", default=DEFAULT_ENV, choices=SCENARIO_IDS, help="scenario id")
    baselines.add_argument(
        "--eval-episodes", type=positive(maximum=MAX_EPISODES), default=30, help="episodes per row (as evaluate's)"
    )
    baselines.add_argument(
        "--seed", type=int, default=0, help="episode seeds start at seed + 10000, as evaluate's (default: 0)"
    )
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


def baselines_command(args: argparse.Namespace) -> int:
    from sb3_marl.common.compiled import announce_compiling
    from sb3_marl.envs.config import with_supervisor
    from sb3_marl.evaluation import evaluate_protocols, markdown_table, run_episodes, summarize
    from sb3_marl.evaluation.baselines import BASELINES
    from sb3_marl.runs.experiment import EVAL_SEED_OFFSET

    env_id = args.env
    if args.density is not None or args.scenario is not None:  # the old --density / --scenario
        scenario = args.scenario or LANE_CHANGE
        env_id = (MERGE_ENV_IDS if scenario == MERGE else ENV_IDS)[args.density or 1]
    output = args.output or Path("logs") / f"baselines_{env_id.replace('/', '-')}.md"
    check_file("-o/--output", output)
    announce_compiling(merge=env_id in MERGE_ENV_IDS.values())
    rows, results = [], []
    start, seed = time.perf_counter(), args.seed + EVAL_SEED_OFFSET
    for name, policy_class in BASELINES.items():
        # n_avs "all": the density's AV counts in turn, the episodes of `evaluate --with-baselines`
        mixed = evaluate_protocols(policy_class(), env_id, args.eval_episodes, seed)
        by_count = [
            ((n_avs, protocol), summarize(run_episodes(env, policy_class(), args.eval_episodes, seed=seed)))
            for n_avs in av_counts(env_id)
            for protocol in args.supervisor
            for env in [make_scenario(env_id, with_supervisor({"n_avs": n_avs}, protocol))]
        ]
        mixed_rows = [
            (("all", protocol), mixed if protocol == "on" else mixed["supervisor_off"]) for protocol in args.supervisor
        ]
        for (n_avs, protocol), summary in [*mixed_rows, *by_count]:
            summary = {key: value for key, value in summary.items() if key != "supervisor_off"}
            label = {"policy": name, "n_avs": n_avs, "supervisor": protocol}
            results.append({**label, **summary})
            rows.append((label, summary))
    table = (
        f"Scenario {env_id}: {args.eval_episodes} episodes per row, seeds {seed}..{seed + args.eval_episodes - 1} "
        "(n_avs all: the density's AV counts in turn, the episodes of `evaluate --with-baselines`)\n\n" + markdown_table(rows)
    )
    print(table)
    write_text(output, table + "\n")
    write_text(output.with_suffix(".json"), json.dumps(results, indent=2))
    print(f"\nwrote {output} and {output.with_suffix('.json')} in {time.perf_counter() - start:.1f} s")
    return 0
