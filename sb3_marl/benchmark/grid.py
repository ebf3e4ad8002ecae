"""The experiment grids (the paper's experiments 1-5 of Zhou, Chen et al., and ours) as lists of trials.

A trial is one (algorithm, density, variant, seed). A *variant* is a named set of hyperparameter
overrides on the algorithm's zoo config (``default`` = the paper's MA2C set-up: local reward, shared
actor-critic trunk, comfort term on, HDV politeness 0). An *experiment* compares curves, each an
(algorithm, variant), on the three densities; a *grid* is one or several experiments, with the
trials they share run once. Variants, experiments and grids are data:
``zoo_configs/grids/variants.yml`` and ``experiments.yml``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from sb3_marl.algos import ALGO_NAMES
from sb3_marl.common.checks import check_choice, check_integer, check_number
from sb3_marl.common.files import read_run_yaml
from sb3_marl.envs import DENSITIES, ENV_IDS, MERGE_ENV_IDS, av_steps_per_env_step
from sb3_marl.runs.hyperparams import CONFIG_DIR
from sb3_marl.sim import LANE_CHANGE, MERGE

#: The paper's budget: 1M env steps (10,000 episodes of 100 steps) per trial.
PAPER_ENV_STEPS = 1_000_000
#: The paper's evaluation: 3 episodes every 200 training episodes.
PAPER_EVAL_EVERY_EPISODES = 200
PAPER_EVAL_EPISODES = 3
PAPER_SEEDS = 2
#: Seeds per trial setting of a grid by default: the authors' code's 3 (0, 2000, 2021), as the
#: committed grids (``results/paper-grid``) ran.
GRID_SEEDS = 3
#: Steps of a full episode (20 s at 5 Hz); evaluation intervals count training episodes of this length.
EPISODE_STEPS = 100

#: The grid as data: ``variants.yml`` (named overrides of the zoo configs) and ``experiments.yml``
#: (experiments and the grids that run them), read and checked on import.
GRID_DIR = CONFIG_DIR / "grids"
#: The keys a variant of ``variants.yml`` may have.
VARIANT_KEYS = ("hyperparams", "extends", "scenario", "curriculum")


def _mapping(value: Any, where: str, expected: str) -> dict[str, Any]:
    if not isinstance(value, dict) or not all(isinstance(key, str) for key in value):
        raise ValueError(f"{where}: expected {expected}, got {value!r}.")
    return value


def load_variants(path: Path) -> tuple[dict[str, dict[str, Any]], tuple[str, ...], dict[str, str]]:
    """The variants of ``path`` (see its header): their hyperparameter overrides (each ``extends``
    resolved), the variants trained on the merge, and the curricula (variant -> its start variant).

    :raises ValueError: naming the file, the variant, the key and what is allowed
    """
    variants: dict[str, dict[str, Any]] = {}
    merge: list[str] = []
    curricula: dict[str, str] = {}
    for name, spec in _mapping(read_run_yaml(path), str(path), "a mapping of variant names").items():
        where = f"{path}: variant {name!r}"
        spec = _mapping({} if spec is None else spec, where, f"a mapping with keys among {list(VARIANT_KEYS)}")
        if set(spec) - set(VARIANT_KEYS):
            raise ValueError(f"{where}: unknown keys {sorted(set(spec) - set(VARIANT_KEYS))}; allowed: {list(VARIANT_KEYS)}.")
        for key in ("extends", "curriculum"):
            if key in spec and spec[key] not in variants:
                raise ValueError(f"{where}: {key} {spec[key]!r} is not a variant defined above it: {list(variants)}.")
        base = spec.get("extends")
        hyperparams = _mapping(spec.get("hyperparams", {}), f"{where}, hyperparams", "a mapping of hyperparameters")
        variants[name] = {**variants.get(base, {}), **hyperparams} if base else dict(hyperparams)
        scenario = spec.get("scenario", MERGE if base in merge else LANE_CHANGE)
        check_choice(f"{where}, scenario", scenario, (LANE_CHANGE, MERGE))
        if scenario == MERGE:
            merge.append(name)
        if "curriculum" in spec:
            curricula[name] = spec["curriculum"]
    return variants, tuple(merge), curricula


def load_experiments(
    path: Path, variants: dict[str, Any]
) -> tuple[dict[str, dict[str, tuple[str, str]]], dict[str, tuple[str, ...]]]:
    """The experiments of ``path`` (label -> (learner, variant) per experiment) and its grids
    (name -> experiments; every experiment is also a grid of its own).

    :raises ValueError: naming the file, the entry and what is allowed
    """
    data = _mapping(read_run_yaml(path), str(path), "a mapping with the keys experiments and grids")
    if set(data) != {"experiments", "grids"}:
        raise ValueError(f"{path}: expected the keys ['experiments', 'grids'], got {sorted(data)}.")
    experiments: dict[str, dict[str, tuple[str, str]]] = {}
    for name, curves in _mapping(data["experiments"], f"{path}: experiments", "a mapping of experiment names").items():
        experiments[name] = {}
        for label, curve in _mapping(curves, f"{path}: experiment {name!r}", "a mapping of curve labels").items():
            where = f"{path}: experiment {name!r}, curve {label!r}"
            if not (isinstance(curve, list) and len(curve) == 2):
                raise ValueError(f"{where}: expected [learner, variant], got {curve!r}.")
            check_choice(f"{where}, learner", curve[0], ALGO_NAMES)
            check_choice(f"{where}, variant", curve[1], variants)
            experiments[name][label] = (curve[0], curve[1])
    grids: dict[str, tuple[str, ...]] = {}
    for name, names in _mapping(data["grids"], f"{path}: grids", "a mapping of grid names").items():
        if name in experiments or not isinstance(names, list) or not names:
            raise ValueError(f"{path}: grid {name!r}: expected a new name and a list of experiments, got {names!r}.")
        for experiment in names:
            check_choice(f"{path}: grid {name!r}, experiment", experiment, experiments)
        grids[name] = tuple(names)
    return experiments, {**grids, **{name: (name,) for name in experiments}}


#: Variant name -> hyperparameter overrides of the algorithm's zoo config; the variants trained
#: on the merge's ids instead of the lane change's; curriculum variants -> the variant of their
#: density-1 start (the trial at density d > 1 starts from the final model of the same learner
#: and seed at density d - 1 and trains its own full budget; no curriculum trial at density 1).
VARIANTS, MERGE_VARIANTS, CURRICULA = load_variants(GRID_DIR / "variants.yml")
#: Experiment -> its curves: label -> (algorithm, variant); grid name -> the experiments it runs.
EXPERIMENTS, GRIDS = load_experiments(GRID_DIR / "experiments.yml", VARIANTS)


@dataclass(frozen=True)
class TrialSpec:
    """One trial: ``algo`` trained on ``density`` with the ``variant``'s overrides and ``seed``."""

    algo: str
    density: int
    variant: str
    seed: int

    def __post_init__(self) -> None:
        """Each field one the grids know (a trial read from a ``trial.json`` names no other file)."""
        check_choice("algo", self.algo, ALGO_NAMES)
        check_choice("density", self.density, DENSITIES)
        check_choice("variant", self.variant, VARIANTS)
        check_integer("seed", self.seed, 0, 2**31 - 1)

    @property
    def trial_id(self) -> str:
        """Folder name of the trial, e.g. ``ma2c_density1_default_seed0``."""
        return f"{self.algo}_density{self.density}_{self.variant}_seed{self.seed}"

    @property
    def env_id(self) -> str:
        """The scenario id: the merge's for :data:`MERGE_VARIANTS`, else the lane change's."""
        return (MERGE_ENV_IDS if self.variant in MERGE_VARIANTS else ENV_IDS)[self.density]

    @property
    def starts_from(self) -> TrialSpec | None:
        """The trial whose final model this one starts from (:data:`CURRICULA`), or None."""
        if self.variant not in CURRICULA or self.density == 1:
            return None
        variant = CURRICULA[self.variant] if self.density == 2 else self.variant
        return TrialSpec(self.algo, self.density - 1, variant, self.seed)

    @property
    def hyperparams(self) -> dict[str, Any]:
        """Overrides of the zoo config (rl-zoo's ``-params``)."""
        return dict(VARIANTS[self.variant])

    def av_steps_per_env_step(self) -> float:
        """AV-steps (SB3 timesteps) per env step with the zoo config's copies: 2 / 3 / 5 at densities 1 / 2 / 3."""
        return av_steps_per_env_step(self.env_id, self.hyperparams.get("env_config"))

    def env_steps(self, timesteps: Any) -> Any:
        """Env steps of ``timesteps`` AV-steps (a number or an array)."""
        return timesteps / self.av_steps_per_env_step()

    def n_timesteps(self, budget: float) -> int:
        """Training AV-steps for ``budget`` (fraction of the paper's 1M env steps)."""
        return max(1, round(budget * PAPER_ENV_STEPS * self.av_steps_per_env_step()))

    def eval_freq(self, eval_every_episodes: float) -> int:
        """AV-steps between evaluations, every ``eval_every_episodes`` training episodes of 100 steps."""
        return max(1, round(eval_every_episodes * EPISODE_STEPS * self.av_steps_per_env_step()))

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def check_budget(budget: float) -> float:
    """The fraction of the paper's 1M env steps per trial: in (0, 1]."""
    return check_number(
        "budget", budget, 0, 1, low_open=True, expected="a fraction in (0, 1] of the paper's 1M env steps per trial"
    )


def make_grid(grid: str = "paper", densities: tuple[int, ...] = tuple(DENSITIES), seeds: int = GRID_SEEDS) -> list[TrialSpec]:
    """The trials of ``grid`` on ``densities`` with seeds ``0 .. seeds-1``, each trial once, a
    curriculum trial after the trials it starts from (added if ``densities`` leaves them out).

    :raises ValueError: naming the bad grid name, density or seed count
    """
    check_choice("grid", grid, GRIDS)
    for density in densities:
        check_choice("density", density, DENSITIES)
    if not isinstance(seeds, int) or seeds < 1:
        raise ValueError(f"Invalid seeds={seeds!r}: expected a number of seeds >= 1.")
    trials: dict[str, TrialSpec] = {}

    def add(spec: TrialSpec) -> None:
        if spec.starts_from is not None:
            add(spec.starts_from)
        trials.setdefault(spec.trial_id, spec)

    for experiment in GRIDS[grid]:
        for algo, variant in EXPERIMENTS[experiment].values():
            for density in sorted(set(densities)):
                for seed in range(seeds):
                    if not (variant in CURRICULA and density == 1):
                        add(TrialSpec(algo, density, variant, seed))
    return list(trials.values())


__all__ = [
    "CURRICULA",
    "EPISODE_STEPS",
    "EXPERIMENTS",
    "GRIDS",
    "GRID_SEEDS",
    "MERGE_VARIANTS",
    "PAPER_ENV_STEPS",
    "PAPER_EVAL_EPISODES",
    "PAPER_EVAL_EVERY_EPISODES",
    "PAPER_SEEDS",
    "VARIANTS",
    "TrialSpec",
    "check_budget",
    "check_choice",
    "load_experiments",
    "load_variants",
    "make_grid",
]
