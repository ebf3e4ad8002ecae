"""The experiment grid of the paper (experiments 1-5 of Zhou, Chen et al., and one of ours) as a list of trials.

A trial is one (algorithm, density, variant, seed). A *variant* is a named set of hyperparameter
overrides on the algorithm's zoo config (``default`` = the paper's MA2C set-up: local reward, shared
actor-critic trunk, comfort term on, HDV politeness 0). An *experiment* compares curves, each an
(algorithm, variant), on the three densities; a *grid* is one or several experiments, with the
trials they share run once.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from sb3_marl.common.checks import check_choice, check_number
from sb3_marl.envs import DENSITIES, ENV_IDS, MERGE_ENV_IDS, av_steps_per_env_step

#: The paper's budget: 1M env steps (10,000 episodes of 100 steps) per trial.
PAPER_ENV_STEPS = 1_000_000
#: The paper's evaluation: 3 episodes every 200 training episodes.
PAPER_EVAL_EVERY_EPISODES = 200
PAPER_EVAL_EPISODES = 3
PAPER_SEEDS = 2
#: Steps of a full episode (20 s at 5 Hz); evaluation intervals count training episodes of this length.
EPISODE_STEPS = 100

#: Variant name -> hyperparameter overrides of the algorithm's zoo config.
VARIANTS: dict[str, dict[str, Any]] = {
    "default": {},
    "global-reward": {"reward_mode": "global"},
    "separate-networks": {"architecture": "separate"},
    "no-comfort": {"env_config": {"comfort": False}},
    "politeness-1": {"env_config": {"hdv_politeness": 1.0}},
    "no-intervention-penalty": {"intervention_penalty": 0.0},
    # training that makes the policy safe on its own (docs/safety.md): half
    # the training episodes without the supervisor, actor and critic on their own networks
    "safety-training": {"architecture": "separate", "supervisor_dropout": 0.5},
    # centralised training, decentralised execution: the critic reads the copy's global state
    "centralised-critic": {"architecture": "separate", "critic": "centralised"},
    # the rule driver as the starting point (sb3_marl/algos/common/rule_prior.py): a DAgger warm start of
    # 300k AV-steps (counted in the budget), then the RL loss plus a prior term whose weight falls
    # from 1 to 0.1 over the next 1M AV-steps
    "rule-prior": {
        "prior": "idm-mobil",
        "prior_warm_start": 300_000,
        "prior_coef": 1.0,
        "prior_coef_final": 0.1,
        "prior_decay_steps": 1_000_000,
    },
}
# the same without the entropy bonus: a sharper policy, whose sampled actions stray less from its argmax
VARIANTS["rule-prior-sharp"] = {**VARIANTS["rule-prior"], "ent_coef": 0.0}
# the same with half the training episodes without the safety supervisor: the sampled policy meets
# the cost of its own mistakes while the prior keeps it near the rule driver
VARIANTS["rule-prior-dropout"] = {**VARIANTS["rule-prior"], "supervisor_dropout": 0.5}
# the prior's weight kept at 1 and no entropy bonus: a policy that stays sharp and close to the rule driver
VARIANTS["rule-prior-strong"] = {**VARIANTS["rule-prior"], "prior_coef_final": 1.0, "ent_coef": 0.0}
# supervisor dropout plus an entropy penalty: imitation leaves the policy spread where the rule
# driver's decision is hard to fit, and sampling those states costs return; the penalty sharpens it
VARIANTS["rule-prior-sharpen"] = {**VARIANTS["rule-prior-dropout"], "ent_coef": -0.05}
# the same with a two and four times stronger penalty: sampled actions closer to the greedy ones
VARIANTS["rule-prior-sharpen-0.1"] = {**VARIANTS["rule-prior-dropout"], "ent_coef": -0.1}
VARIANTS["rule-prior-sharpen-0.2"] = {**VARIANTS["rule-prior-dropout"], "ent_coef": -0.2}
# the prior's weight falling to 0: where the learned argmax is not the rule action, a prior kept at a
# floor holds probability on both against the penalty, and sampling picks the rule action's
VARIANTS["rule-prior-sharpen-free"] = {**VARIANTS["rule-prior-sharpen-0.1"], "prior_coef_final": 0.0}
# the prior kept, as the expected disagreement instead of the cross-entropy: it lets go where the
# policy has committed to another action instead of holding probability on both
VARIANTS["rule-prior-agreement"] = {**VARIANTS["rule-prior-sharpen-0.1"], "prior_form": "agreement"}
# the same with the prior's floor at 0.5: a stronger pull toward the rule action where the policy still
# gives it probability
VARIANTS["rule-prior-agreement-0.5"] = {**VARIANTS["rule-prior-agreement"], "prior_coef_final": 0.5}
VARIANTS["rule-prior-agreement-0.75"] = {**VARIANTS["rule-prior-agreement"], "prior_coef_final": 0.75}
# the disagreement prior with the safety supervisor in shadow in the episodes run without it and a
# 4x intervention penalty: every unsafe proposal costs, supervised or not (docs/safety.md)
VARIANTS["rule-prior-agreement-shadow"] = {
    **VARIANTS["rule-prior-agreement"],
    "env_config": {"supervisor_shadow": True},
    "intervention_penalty": 20.0,
}
# the floor-0.5 recipe storing the supervisor's executed action instead of the proposal in the episodes
# it supervises: the brake it applied is credited, not the IDLE the policy proposed
VARIANTS["rule-prior-agreement-0.5-executed"] = {**VARIANTS["rule-prior-agreement-0.5"], "stored_actions": "executed"}
# the on-ramp merge (sb3_marl/Merge-density<d>-v0) with its zoo config as it is
VARIANTS["merge"] = {}
# the merging paper's curriculum: density 2 starts from density 1's model, density 3 from density 2's
VARIANTS["merge-curriculum"] = {}
# the merge trained (and evaluated) with the supervisor holding the AVs' lane changes to MOBIL's
# safety check for the HDV they cut in front of (docs/safety.md)
VARIANTS["merge-mobil-safety"] = {"env_config": {"supervisor_mobil_safety": True}}
#: Variants trained on the merge scenario's ids instead of the lane change's.
MERGE_VARIANTS = ("merge", "merge-curriculum", "merge-mobil-safety")
#: Curriculum variants -> the variant of their density-1 start: the trial at density d > 1 starts from
#: the final model of the same learner and seed at density d - 1 and trains its own full budget
#: (no curriculum trial at density 1: that is the start's).
CURRICULA = {"merge-curriculum": "merge"}

#: Experiment -> its curves: label -> (algorithm, variant). In the order of the paper's sections.
EXPERIMENTS: dict[str, dict[str, tuple[str, str]]] = {
    "reward": {"local reward": ("ma2c", "default"), "global reward": ("ma2c", "global-reward")},
    "sharing": {"shared actor-critic": ("ma2c", "default"), "separate actor and critic": ("ma2c", "separate-networks")},
    "comfort": {"comfort on": ("ma2c", "default"), "comfort off": ("ma2c", "no-comfort")},
    "politeness": {"HDV politeness p=0": ("ma2c", "default"), "HDV politeness p=1": ("ma2c", "politeness-1")},
    "baselines": {
        "MADQN": ("madqn", "default"),
        "MA2C": ("ma2c", "default"),
        "MAACKTR": ("maacktr", "default"),
        "MAPPO": ("mappo", "default"),
    },
    # beyond the paper: MA2C's training-only penalty for overruled proposals (zoo_configs/ma2c.yml)
    "penalty": {
        "intervention penalty (ours)": ("ma2c", "default"),
        "no penalty (the authors' reward)": ("ma2c", "no-intervention-penalty"),
    },
    # beyond the paper: training that makes the policy safe without the supervisor
    "safety": {
        "behind the supervisor (default)": ("ma2c", "default"),
        "safety training": ("ma2c", "safety-training"),
    },
    # beyond the paper: learners started from, and regularised toward, the IDM/MOBIL rule driver
    "rule-prior": {
        "MA2C, rule prior": ("ma2c", "rule-prior"),
        "MAPPO, rule prior": ("mappo", "rule-prior"),
        "MADQN, rule prior": ("madqn", "rule-prior"),
        "MA2C, rule prior, no entropy bonus": ("ma2c", "rule-prior-sharp"),
        "MA2C, rule prior, supervisor dropout": ("ma2c", "rule-prior-dropout"),
        "MA2C, rule prior kept strong": ("ma2c", "rule-prior-strong"),
        "MA2C, rule prior, supervisor dropout, entropy penalty": ("ma2c", "rule-prior-sharpen"),
        "MA2C, rule prior, supervisor dropout, entropy penalty 0.1": ("ma2c", "rule-prior-sharpen-0.1"),
        "MA2C, rule prior, supervisor dropout, entropy penalty 0.2": ("ma2c", "rule-prior-sharpen-0.2"),
        "MA2C, rule prior falling to 0, supervisor dropout, entropy penalty 0.1": ("ma2c", "rule-prior-sharpen-free"),
        "MA2C, rule prior as disagreement, supervisor dropout, entropy penalty 0.1": ("ma2c", "rule-prior-agreement"),
        "MA2C, rule prior as disagreement (floor 0.5), supervisor dropout, entropy penalty 0.1": (
            "ma2c",
            "rule-prior-agreement-0.5",
        ),
        "MA2C, rule prior as disagreement (floor 0.75), supervisor dropout, entropy penalty 0.1": (
            "ma2c",
            "rule-prior-agreement-0.75",
        ),
        "MA2C, rule prior as disagreement, supervisor dropout and shadow, penalty 20, entropy penalty 0.1": (
            "ma2c",
            "rule-prior-agreement-shadow",
        ),
        "MA2C, rule prior as disagreement (floor 0.5), executed actions stored": (
            "ma2c",
            "rule-prior-agreement-0.5-executed",
        ),
        "MAPPO, rule prior as disagreement (floor 0.5), supervisor dropout, entropy penalty 0.1": (
            "mappo",
            "rule-prior-agreement-0.5",
        ),
    },
    # the merging paper's scenario (Chen et al. 2021, docs/merge.md): its four learners
    "merge": {
        "MADQN, merge": ("madqn", "merge"),
        "MA2C, merge": ("ma2c", "merge"),
        "MAACKTR, merge": ("maacktr", "merge"),
        "MAPPO, merge": ("mappo", "merge"),
    },
    # the merging paper's curriculum: MA2C at densities 2 and 3 started from the easier density's model
    "curriculum": {
        "MA2C, merge, from scratch": ("ma2c", "merge"),
        "MA2C, merge, curriculum": ("ma2c", "merge-curriculum"),
    },
    # beyond the merging paper: MA2C trained with the supervisor's MOBIL safety check on
    "mobil-safety": {
        "MA2C, merge (default supervisor)": ("ma2c", "merge"),
        "MA2C, merge, MOBIL safety check": ("ma2c", "merge-mobil-safety"),
    },
    # beyond the paper: CTDE, a critic that sees every AV of the copy (same networks otherwise)
    "ctde": {
        "local critic (separate networks)": ("ma2c", "separate-networks"),
        "centralised critic": ("ma2c", "centralised-critic"),
    },
}

#: Grid name -> the experiments it runs.
#: The "paper" grid: the paper's five experiments and our intervention-penalty one (81 trials with 3 seeds).
GRIDS: dict[str, tuple[str, ...]] = {
    "paper": ("reward", "sharing", "comfort", "politeness", "baselines", "penalty"),
    **{name: (name,) for name in EXPERIMENTS},
}


@dataclass(frozen=True)
class TrialSpec:
    """One trial: ``algo`` trained on ``density`` with the ``variant``'s overrides and ``seed``."""

    algo: str
    density: int
    variant: str
    seed: int

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


def make_grid(grid: str = "paper", densities: tuple[int, ...] = tuple(DENSITIES), seeds: int = PAPER_SEEDS) -> list[TrialSpec]:
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
    "MERGE_VARIANTS",
    "PAPER_ENV_STEPS",
    "PAPER_EVAL_EPISODES",
    "PAPER_EVAL_EVERY_EPISODES",
    "PAPER_SEEDS",
    "VARIANTS",
    "TrialSpec",
    "check_budget",
    "check_choice",
    "make_grid",
]
