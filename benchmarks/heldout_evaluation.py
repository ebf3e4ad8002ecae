"""Evaluate grid trials and IDM/MOBIL on held-out episodes under both supervisor protocols.

The learned-policy targets are measured on episode seeds never used in training (resets from the
training seed) or in evaluation during training and the paper's final evaluation (10000..10029):
300 episodes with seeds 100000..100299 by default, actions sampled (the authors' protocol), masks,
with the safety supervisor and without it, and IDM/MOBIL on the same episodes.

    python benchmarks/heldout_evaluation.py -f results/paper-grid --variants default safety-training \
        --densities 1 2 3 --seeds 3 -o results/safety

writes ``<output>/heldout.json`` (every trial's and IDM/MOBIL's summaries with each episode's return;
finished entries are kept and skipped on a rerun) and ``<output>/heldout.md`` (per variant and density:
mean ± std over seeds of the return, its IQM with a 95 % stratified-bootstrap CI over seeds where every
entry kept its episode returns, collision rate, lane changes and yields per episode, under each protocol).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from sb3_marl.baselines import IDMMobilPolicy
from sb3_marl.benchmark.grid import TrialSpec
from sb3_marl.benchmark.statistics import iqm_with_ci
from sb3_marl.envs import ENV_IDS
from sb3_marl.envs.supervisor import VERSION as SUPERVISOR_VERSION
from sb3_marl.evaluation import evaluate_protocols, model_policy
from sb3_marl.runs import find_run

METRICS = ("return_mean", "collision_rate", "lane_changes_per_episode", "yields_per_episode")


def slim(result: dict) -> dict:
    """A protocol result with its per-episode returns rounded to 3 decimals (the IQM's input)."""
    return {**result, "returns": [round(float(r), 3) for r in result["returns"]]}


def evaluate_all(args: argparse.Namespace) -> dict:
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "heldout.json"
    results = json.loads(path.read_text()) if path.is_file() else {}
    if results.get("protocol", {}).get("supervisor_version") != SUPERVISOR_VERSION:
        results = {}  # evaluated under another safety supervisor: start afresh
    results["protocol"] = {"episodes": args.episodes, "seeds": [args.seed, args.seed + args.episodes - 1],
                           "actions": "sampled (the authors' protocol), action masks",
                           "supervisor": "on (top level) and off (supervisor_off)",
                           "supervisor_version": SUPERVISOR_VERSION}
    jobs = [(f"idm-mobil_density{d}", None, d) for d in args.densities]
    jobs += [(TrialSpec(args.algo, d, v, s).trial_id, TrialSpec(args.algo, d, v, s), d)
             for v in args.variants for d in args.densities for s in range(args.seeds)]
    for name, spec, density in tqdm(jobs, desc="held-out evaluations", unit="policy"):
        if name in results.get("entries", {}):
            continue
        start = time.perf_counter()
        if spec is None:
            policy, config = IDMMobilPolicy(), {"safety_supervisor": True}
        else:
            folder = Path(args.log_folder) / "trials" / spec.trial_id
            if not (folder / "result.json").is_file():
                print(f"skipped {name}: not finished")
                continue
            run = find_run(folder, spec.algo, spec.env_id)
            policy, config = model_policy(run.load_model("cpu")), run.env_config
        result = evaluate_protocols(policy, ENV_IDS[density], args.episodes, args.seed, config)
        entry = {**slim(result), "supervisor_off": slim(result["supervisor_off"]),
                 "wall_time_s": round(time.perf_counter() - start, 1)}
        results.setdefault("entries", {})[name] = entry
        path.write_text(json.dumps(results, indent=2) + "\n")
    return results


def table(results: dict, variants: list[str], densities: list[int], seeds: int, algo: str) -> str:
    entries = results["entries"]
    lines = [f"Held-out evaluation: {results['protocol']['episodes']} episodes, seeds "
             f"{results['protocol']['seeds'][0]}..{results['protocol']['seeds'][1]}, actions sampled, masks; "
             "learners: mean ± std over training seeds; IQM over every (seed, episode) return, its CI by stratified "
             "bootstrap over seeds (IDM/MOBIL, one policy: over episodes).", "",
             "| policy | density | seeds | supervisor on: return | IQM [95 % CI] | collision | supervisor off: return "
             "| IQM [95 % CI] | collision | lane changes / ep. (off) | yields / ep. (off) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for density in densities:
        rows = [("IDM/MOBIL", [entries.get(f"idm-mobil_density{density}")])]
        rows += [(f"{algo} {variant}", [entries.get(TrialSpec(algo, density, variant, s).trial_id) for s in range(seeds)])
                 for variant in variants]
        for label, found in rows:
            found = [e for e in found if e]
            if not found:
                continue

            def cell(metric: str, off: bool = False, spread: bool = True, found: list = found) -> str:
                values = np.array([(e["supervisor_off"] if off else e)[metric] for e in found])
                return f"{values.mean():.2f} ± {values.std():.2f}" if spread else f"{values.mean():.3f}"

            def iqm(off: bool = False, found: list = found) -> str:
                returns = [(e["supervisor_off"] if off else e).get("returns") for e in found]
                if not all(returns):
                    return "—"
                # seeds resampled within each episode; one policy alone (IDM/MOBIL): episodes resampled
                value, low, high = iqm_with_ci(np.array(returns) if len(returns) > 1 else np.array(returns[0])[:, None])
                return f"{value:.2f} [{low:.2f}, {high:.2f}]"

            lines.append(f"| {label} | {density} | {len(found)} | {cell('return_mean')} | {iqm()} | "
                         f"{cell('collision_rate', spread=False)} | {cell('return_mean', True)} | {iqm(True)} | "
                         f"{cell('collision_rate', True, False)} | {cell('lane_changes_per_episode', True, False)} | "
                         f"{cell('yields_per_episode', True, False)} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-f", "--log-folder", default="results/paper-grid")
    parser.add_argument("--algo", default="ma2c")
    parser.add_argument("--variants", nargs="+", default=["default"])
    parser.add_argument("--densities", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--episodes", type=int, default=300)
    parser.add_argument("--seed", type=int, default=100_000, help="first episode seed (default: 100000)")
    parser.add_argument("-o", "--output", default="results/safety")
    args = parser.parse_args()
    torch.set_num_threads(1)
    results = evaluate_all(args)
    text = table(results, args.variants, args.densities, args.seeds, args.algo)
    (Path(args.output) / "heldout.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
