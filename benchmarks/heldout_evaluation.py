"""Evaluate grid trials and IDM/MOBIL on held-out episodes under both supervisor protocols.

The learned-policy targets are measured on episode seeds never used in training (resets from the
training seed) or in evaluation during training and the paper's final evaluation (10000..10029):
300 episodes with seeds 100000..100299 by default, actions sampled (the authors' protocol) and with
``--greedy`` also argmax, masks, with the safety supervisor and without it, and IDM/MOBIL on the
same episodes.

    python benchmarks/heldout_evaluation.py -f results/paper-grid --algo ma2c mappo --variants rule-prior \
        --densities 1 2 3 --seeds 3 --greedy -o results/rule-prior

``--traffic`` also records every vehicle's trip (``<output>/trips/<entry>.csv.gz``, both supervisor
protocols, sampled actions), keeps the traffic metrics in each entry, adds the all-human reference
(every AV an HDV, the same episodes) and writes ``<output>/traffic.md``.

``--config key:value ...`` sets env config keys for every policy (e.g. ``supervisor_joint_search:True``:
a supervisor variant on the same episodes; give it another ``--output``). It writes
``<output>/heldout.json`` (every trial's and IDM/MOBIL's summaries with each episode's return;
finished entries are kept and skipped on a rerun) and ``<output>/heldout.md`` (per algorithm, variant,
action protocol and density: mean ± std over seeds of the return, its IQM with a 95 % stratified-bootstrap
CI over seeds, the pooled collision count with its 95 % Clopper–Pearson upper bound, agreement with the
rule driver, lane changes and yields per episode, under each supervisor protocol).
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd
import torch
from tqdm import tqdm

from sb3_marl.algos.common.policies import model_policy
from sb3_marl.benchmark.grid import MERGE_VARIANTS, TrialSpec
from sb3_marl.benchmark.statistics import clopper_pearson_upper, iqm_with_ci
from sb3_marl.cli.common import StoreHyperparams
from sb3_marl.common.files import write_text
from sb3_marl.envs import ENV_IDS, MERGE_ENV_IDS, av_counts, make_scenario
from sb3_marl.envs.config import LANE_CHANGE, MERGE, scenario_default_config, supervisor_version, validate_config
from sb3_marl.evaluation import evaluate_protocols
from sb3_marl.evaluation.baselines import IDMMobilPolicy
from sb3_marl.evaluation.episodes import run_episodes
from sb3_marl.evaluation.traffic_plots import PositionTrace, plot_encounters, plot_time_space
from sb3_marl.evaluation.trips import human_reference, traffic_table, trips_csv
from sb3_marl.runs.folders import find_run


def slim(result: dict) -> dict:
    """A protocol result with its per-episode returns rounded to 3 decimals (the IQM's input)."""
    return {**result, "returns": [round(float(r), 3) for r in result["returns"]]}


def evaluate_all(args: argparse.Namespace) -> dict:
    merge = [v in MERGE_VARIANTS for v in args.variants]
    if any(merge) and not all(merge):
        raise SystemExit(f"--variants {args.variants}: the lane change's and the merge's variants go to separate outputs.")
    scenario = MERGE if all(merge) else LANE_CHANGE
    try:
        validate_config({**scenario_default_config(scenario), **args.config}, scenario)
    except ValueError as error:
        raise SystemExit(f"--config: {error}") from None
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "heldout.json"
    results = json.loads(path.read_text()) if path.is_file() else {}
    earlier, version = results.get("protocol", {}), supervisor_version(args.config, scenario)
    if earlier.get("supervisor_version") != version or earlier.get("config", {}) != args.config:
        results = {}  # evaluated under another safety supervisor or env config: start afresh
    results["protocol"] = {
        "episodes": args.episodes,
        "seeds": [args.seed, args.seed + args.episodes - 1],
        "actions": "sampled (the authors' protocol)" + (" and greedy (argmax)" if args.greedy else "") + ", action masks",
        "supervisor": "on (top level) and off (supervisor_off)",
        "supervisor_version": version,
        **({"config": args.config} if args.config else {}),
    }
    ids = MERGE_ENV_IDS if scenario == MERGE else ENV_IDS  # the scenario of IDM/MOBIL's reference rows
    jobs = [(f"idm-mobil_density{d}", None, d) for d in args.densities]
    jobs += [(f"all-human_density{d}", "human", d) for d in args.densities] if args.traffic else []
    jobs += [
        (TrialSpec(algo, d, v, s).trial_id, TrialSpec(algo, d, v, s), d)
        for algo in args.algo
        for v in args.variants
        for d in args.densities
        for s in range(args.seeds)
    ]
    for name, spec, density in tqdm(jobs, desc="held-out evaluations", unit="policy"):
        if name in results.get("entries", {}):
            continue
        start = time.perf_counter()
        if spec == "human":
            human = human_reference(ids[density], args.episodes, args.seed, args.config)
            write_trips(out / "trips" / f"{name}.csv.gz", [{"supervisor": "-", **trip} for trip in human.trips()])
            results.setdefault("entries", {})[name] = {
                "traffic": human.metrics(),
                "wall_time_s": round(time.perf_counter() - start, 1),
            }
            write_text(path, json.dumps(results, indent=2) + "\n")
            continue
        if spec is None:
            policies, config = {"sampled": IDMMobilPolicy()}, {"safety_supervisor": True, **args.config}
        else:
            folder = Path(args.log_folder) / "trials" / spec.trial_id
            if not (folder / "result.json").is_file():
                print(f"skipped {name}: not finished")
                continue
            run = find_run(folder, spec.algo, spec.env_id)
            model = run.load_model("cpu")
            policies, config = {"sampled": model_policy(model)}, {**run.env_config, **args.config}
            if args.greedy:
                policies["greedy"] = model_policy(model, deterministic=True)
        entry: dict = {}
        for actions, policy in policies.items():
            env_id = ids[density] if spec is None else spec.env_id
            traffic = args.traffic and actions == "sampled"
            result = evaluate_protocols(policy, env_id, args.episodes, args.seed, config, traffic=traffic)
            if traffic:
                trips = [
                    {"supervisor": p, **t}
                    for p, r in (("on", result), ("off", result["supervisor_off"]))
                    for t in r.pop("trips")
                ]
                write_trips(out / "trips" / f"{name}.csv.gz", trips)
            evaluated = {**slim(result), "supervisor_off": slim(result["supervisor_off"])}
            entry.update(evaluated if actions == "sampled" else {actions: evaluated})
        entry["wall_time_s"] = round(time.perf_counter() - start, 1)
        results.setdefault("entries", {})[name] = entry
        write_text(path, json.dumps(results, indent=2) + "\n")  # atomic: a kill keeps the finished entries
    return results


def write_trips(path: Path, trips: list[dict]) -> None:
    """Trip records as gzipped CSV (``pandas.read_csv`` reads it), the same bytes for the same trips."""
    path.parent.mkdir(parents=True, exist_ok=True)
    data = gzip.compress(trips_csv(trips).encode(), mtime=0)
    temporary = path.with_name(f".{path.name}.{os.getpid()}")
    temporary.write_bytes(data)
    os.replace(temporary, path)


def traffic_tables(results: dict, variants: list[str], densities: list[int], seeds: int, algos: list[str]) -> str:
    """Per density: the all-human reference, IDM/MOBIL and each (algorithm, variant) with sampled
    actions under each supervisor protocol: each traffic metric's mean over training seeds."""
    entries, protocol = results["entries"], results["protocol"]
    lines = [
        f"Traffic on held-out episodes: {protocol['episodes']} episodes, seeds {protocol['seeds'][0]}.."
        f"{protocol['seeds'][1]}, sampled actions, safety supervisor v{protocol['supervisor_version']} on and off; "
        "every vehicle, AVs and HDVs (docs/traffic.md); learners: mean over training seeds; all human: "
        "the same episodes with every AV an HDV.",
        "",
    ]
    for density in densities:
        rows = [({"policy": "all human (no AV)", "seeds": 1, "supervisor": "-"}, entries.get(f"all-human_density{density}"))]
        found = {"IDM/MOBIL": [entries.get(f"idm-mobil_density{density}")]}
        for algo in algos:
            for variant in variants:
                found[f"{algo} {variant}"] = [entries.get(TrialSpec(algo, density, variant, s).trial_id) for s in range(seeds)]
        for label, entries_ in found.items():
            entries_ = [e for e in entries_ if e and "traffic" in e]
            for supervisor in ("on", "off"):
                metrics = [(e if supervisor == "on" else e["supervisor_off"])["traffic"] for e in entries_]
                if metrics:
                    mean = {key: float(np.mean([m[key] for m in metrics])) for key in metrics[0]}
                    rows.append(({"policy": label, "seeds": len(metrics), "supervisor": supervisor}, {"traffic": mean}))
        rows = [(label, entry["traffic"]) for label, entry in rows if entry]
        if rows:
            lines += [f"Density {density}:", "", traffic_table(rows), ""]
    return "\n".join(lines)


def traffic_figures(args: argparse.Namespace, results: dict) -> list[Path]:
    """Per density: ``encounters_density<d>.png`` (each vehicle's minimum TTC and time headway, supervisor
    on: the all-human reference, IDM/MOBIL and each learner's first seed) and ``time_space_density<d>.png``
    (the first held-out episode of the same policies)."""
    out, written = Path(args.output), []
    scenario_ids = MERGE_ENV_IDS if all(v in MERGE_VARIANTS for v in args.variants) else ENV_IDS
    for density in args.densities:
        specs = {f"{a} {v}": TrialSpec(a, density, v, 0) for a in args.algo for v in args.variants}
        names = {"all human (no AV)": f"all-human_density{density}", "IDM/MOBIL": f"idm-mobil_density{density}"}
        names |= {label: spec.trial_id for label, spec in specs.items()}
        trips = {}
        for label, name in names.items():
            path = out / "trips" / f"{name}.csv.gz"
            if path.is_file():
                frame = pd.read_csv(path)
                trips[label] = frame[frame["supervisor"].astype(str).isin(["on", "-"])].to_dict("records")
        written.append(plot_encounters(trips, out / f"encounters_density{density}.png", f"density {density}, supervisor on"))
        traces = {label: PositionTrace() for label in names}
        human_reference(scenario_ids[density], 1, args.seed, args.config, also=(traces["all human (no AV)"],))
        first = {"n_avs": av_counts(scenario_ids[density], args.config)[0]}  # the first held-out episode's AVs
        env = make_scenario(scenario_ids[density], {"safety_supervisor": True, **args.config, **first})
        run_episodes(env, IDMMobilPolicy(), 1, args.seed, on_step=traces["IDM/MOBIL"])
        for label, spec in specs.items():
            run = find_run(Path(args.log_folder) / "trials" / spec.trial_id, spec.algo, spec.env_id)
            env = make_scenario(spec.env_id, {**run.env_config, "safety_supervisor": True, **args.config, **first})
            run_episodes(env, model_policy(run.load_model("cpu")), 1, args.seed, on_step=traces[label])
        title = f"{scenario_ids[density]}, episode seed {args.seed}, supervisor on"
        written.append(plot_time_space(traces, out / f"time_space_density{density}.png", title))
    return written


def table(results: dict, variants: list[str], densities: list[int], seeds: int, algos: list[str]) -> str:
    """Per density: IDM/MOBIL and each (algorithm, variant) under each action protocol, with the
    supervisor and without: return over training seeds, its IQM, the pooled collision rate with
    its 95 % Clopper–Pearson upper bound, agreement with the rule driver, lane changes, yields."""
    entries, episodes = results["entries"], results["protocol"]["episodes"]
    merge = any("merge_rate" in entry for entry in entries.values())  # the merge's metrics too
    lines = [
        f"Held-out evaluation: {episodes} episodes, seeds {results['protocol']['seeds'][0]}.."
        f"{results['protocol']['seeds'][1]}, {results['protocol']['actions']}, safety supervisor "
        f"v{results['protocol']['supervisor_version']} on and off"
        + "".join(f", {key}: {value}" for key, value in results["protocol"].get("config", {}).items())
        + "; learners: mean ± std over training seeds; "
        "IQM over every (seed, episode) return, its CI by stratified bootstrap over seeds (IDM/MOBIL, one "
        "policy: over episodes); collisions pooled over seeds with the 95 % Clopper–Pearson upper bound; "
        "agreement: share of AV-steps whose proposed action is the rule driver's (IDM/MOBIL).",
        "",
        "| policy | actions | density | seeds | supervisor | return | IQM [95 % CI] | collisions | "
        "collision rate (95 % upper) | agreement | lane changes / ep. | yields / ep. |"
        + (" ramp AVs merged | time to merge [s] | stranded / ep. |" if merge else ""),
        "|---|---|---|---|---|---|---|---|---|---|---|---|" + ("---|---|---|" if merge else ""),
    ]
    for density in densities:
        rows = [("IDM/MOBIL", "rules", [entries.get(f"idm-mobil_density{density}")])]
        for algo in algos:
            for variant in variants:
                found = [entries.get(TrialSpec(algo, density, variant, s).trial_id) for s in range(seeds)]
                rows.append((f"{algo} {variant}", "sampled", found))
                rows.append((f"{algo} {variant}", "greedy", [e.get("greedy") if e else None for e in found]))
        for label, actions, found in rows:
            found = [e for e in found if e]
            if not found:
                continue
            for supervisor in ("on", "off"):
                results_ = [e if supervisor == "on" else e["supervisor_off"] for e in found]
                means = np.array([r["return_mean"] for r in results_])
                returns = [r.get("returns") for r in results_]
                if all(returns):
                    scores = np.array(returns) if len(returns) > 1 else np.array(returns[0])[:, None]
                    value, low, high = iqm_with_ci(scores)
                    iqm = f"{value:.2f} [{low:.2f}, {high:.2f}]"
                else:
                    iqm = "—"
                n = sum(r["episodes"] for r in results_)
                crashes = int(round(sum(r["collision_rate"] * r["episodes"] for r in results_)))
                upper = clopper_pearson_upper(crashes, n)
                mean = lambda key, rs=results_: np.mean([r.get(key, float("nan")) for r in rs])  # noqa: E731
                lines.append(
                    f"| {label} | {actions} | {density} | {len(found)} | {supervisor} | "
                    f"{means.mean():.2f} ± {means.std():.2f} | {iqm} | {crashes} / {n} | "
                    f"{crashes / n:.4f} ({upper:.4f}) | {mean('rule_agreement'):.3f} | "
                    f"{mean('lane_changes_per_episode'):.2f} | {mean('yields_per_episode'):.2f} |"
                    + (
                        f" {mean('merge_rate'):.3f} | {mean('time_to_merge_mean'):.2f} | {mean('stranded_per_episode'):.2f} |"
                        if merge
                        else ""
                    )
                )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-f", "--log-folder", default="results/paper-grid")
    parser.add_argument("--algo", nargs="+", default=["ma2c"])
    parser.add_argument("--greedy", action="store_true", help="also evaluate the argmax policy")
    parser.add_argument("--variants", nargs="+", default=["default"])
    parser.add_argument("--densities", type=int, nargs="+", default=[1, 2, 3])
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--episodes", type=int, default=300)
    parser.add_argument("--seed", type=int, default=100_000, help="first episode seed (default: 100000)")
    parser.add_argument(
        "--config", nargs="+", default={}, action=StoreHyperparams, metavar="KEY:VALUE", help="env config keys to set"
    )
    parser.add_argument("--traffic", action="store_true", help="trip records, traffic metrics and the all-human reference")
    parser.add_argument("-o", "--output", default="results/safety")
    args = parser.parse_args()
    torch.set_num_threads(1)
    results = evaluate_all(args)
    text = table(results, args.variants, args.densities, args.seeds, args.algo)
    write_text(Path(args.output) / "heldout.md", text)
    print(text)
    if args.traffic:
        traffic = traffic_tables(results, args.variants, args.densities, args.seeds, args.algo)
        write_text(Path(args.output) / "traffic.md", traffic)
        print(traffic)
        for figure in traffic_figures(args, results):
            print(f"wrote {figure}")


if __name__ == "__main__":
    main()
