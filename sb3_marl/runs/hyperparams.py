"""rl-zoo-style hyperparameters: one YAML per algorithm in ``zoo_configs/``, keyed by env id.

Besides the algorithm's own constructor arguments (and rl-zoo's ``n_timesteps`` and ``policy``),
an entry may set the scenario and the wrapper:

- ``reward_mode``: ``local`` (default), ``global`` or ``individual``
- ``n_copies``: scenario copies (default: one per AV count of the density)
- ``env_config``: scenario overrides, e.g. ``{hdv_politeness: 1.0, comfort: false}``
- ``reward_scale``: factor applied to the training rewards (the MARL_CAVs code uses 0.05)
- ``intervention_penalty``: subtracted from an AV's training reward (paper units, before the
  scale) when the safety supervisor replaced its proposed action (default 0: the paper's reward)
- ``architecture``: ``shared`` or ``separate`` MA2C network (actor-critic algorithms), or
  ``default`` for SB3's own MLP

- ``stored_actions``: ``proposed`` (default, the authors') or ``executed``: which action the
  learner stores where the safety supervisor replaced the policy's
- ``supervisor_dropout``: probability in [0, 1] that a training episode runs without the safety
  supervisor (default 0); evaluation is unaffected
- ``critic`` (``ma2c``, ``mappo``, ``maacktr``): ``local`` (default: the critic sees the AV's own
  view, as the actor) or ``centralised`` (CTDE: the critic sees the global state of the AV's
  scenario copy, :class:`~sb3_marl.algos.common.policies.CentralisedCriticPolicy`; needs ``architecture: separate``)

and ``safety_loss_coef`` (``ma2c``, ``mappo``, ``madqn``): weight of the loss that teaches the
policy the safety supervisor's replacements (default 0, see :mod:`sb3_marl.algos.common.teacher`);

and the rule prior (``ma2c``, ``mappo``, ``maacktr``, ``madqn``; :mod:`sb3_marl.algos.common.rule_prior`): ``prior``
(``idm-mobil`` or null), ``prior_warm_start`` (AV-steps of the DAgger warm start; MADQN: of the
rule driver driving), ``prior_coef`` / ``prior_coef_final`` / ``prior_decay_steps`` (the
regularisation's weight, falling linearly over that many AV-steps after the warm start), and for
the actor-critics ``prior_smoothing`` and ``prior_form``;

and the maskable learners (``ma2c``, ``mappo``, ``maacktr``, ``madqn``) take ``action_masking``
(true in every zoo config, the authors' choice; false for the unmasked ablation).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import yaml

from sb3_marl.algos import get_algo
from sb3_marl.algos.common.base import hyperparameters
from sb3_marl.algos.common.policies import (
    ACTOR_CRITIC_FUSED_ADAM,
    ARCHITECTURES,
    CentralisedCriticPolicy,
    LocalViewExtractor,
    check_network_size,
    ma2c_policy_kwargs,
    ma2c_q_policy_kwargs,
)
from sb3_marl.common.checks import is_integer, is_number
from sb3_marl.common.files import load_yaml
from sb3_marl.envs import av_counts, scenario_of, validate_config
from sb3_marl.envs.config import scenario_default_config
from wrappers.parameter_sharing import check_sharing_options, check_supervisor_dropout
from wrappers.reward_scale import check_penalty, check_reward_scale

CONFIG_DIR = Path(__file__).resolve().parents[2] / "zoo_configs"
#: Algorithms registered under two names share one file: ``acktr`` reads ``maacktr.yml``.
CONFIG_FILES = {"acktr": "maacktr"}
SCENARIO_KEYS = (
    "reward_mode",
    "n_copies",
    "env_config",
    "reward_scale",
    "intervention_penalty",
    "architecture",
    "stored_actions",
    "supervisor_dropout",
    "critic",
)
#: What the learner stores when the safety supervisor replaced an action: the policy's proposal
#: (the authors' choice) or the action executed.
STORED_ACTIONS = ("proposed", "executed")
ZOO_KEYS = ("n_timesteps", "policy")
#: Critic inputs of the actor-critic learners: the AV's own view, or its copy's global state (CTDE).
CRITICS = ("local", "centralised")
#: The learners whose critic may be centralised (sb3-contrib's maskable actor-critic machinery).
CENTRALISED_CRITIC_ALGOS = ("ma2c", "mappo", "maacktr", "acktr")
#: The policy alias of a centralised critic.
CENTRALISED_POLICY = CentralisedCriticPolicy.__name__
#: Constructor arguments the training code sets itself.
RESERVED_KEYS = ("env", "seed", "device", "tensorboard_log", "verbose", "_init_setup_model")


def load_hyperparams(algo: str, env_id: str, path: str | Path | None = None) -> dict[str, Any]:
    """The entry of ``env_id`` in ``zoo_configs/<algo>.yml`` (or ``path``), validated."""
    get_algo(algo)
    path = Path(path) if path is not None else config_file(algo)
    if not path.is_file():
        raise ValueError(f"No hyperparameter file for algorithm {algo!r}: {path} does not exist.")
    try:
        entries = load_yaml(path) or {}
    except yaml.YAMLError as error:
        raise ValueError(f"{path} is not valid YAML: {error}") from None
    if not isinstance(entries, dict):
        raise ValueError(f"{path} must map env ids to hyperparameters, got a {type(entries).__name__}.")
    if env_id not in entries:
        raise ValueError(f"{path} has no entry for env {env_id!r}: it has {sorted(entries)}.")
    if not isinstance(entries[env_id], dict):
        raise ValueError(f"{path}: the entry of {env_id!r} must map hyperparameters to values, got {entries[env_id]!r}.")
    hyperparams = parse_string_values(entries[env_id])
    validate_hyperparams(algo, hyperparams, env_id)
    return hyperparams


def merge_hyperparams(base: dict[str, Any], overrides: dict[str, Any] | None) -> dict[str, Any]:
    """``base`` updated with ``overrides``; ``env_config`` is merged key by key, so that overriding
    one scenario key (``env_config: {comfort: false}``) keeps the entry's others (the supervisor)."""
    overrides = overrides or {}
    merged = {**base, **overrides}
    if isinstance(base.get("env_config"), dict) and isinstance(overrides.get("env_config"), dict):
        merged["env_config"] = {**base["env_config"], **overrides["env_config"]}
    return merged


def config_file(algo: str) -> Path:
    """The zoo config file of an algorithm: ``zoo_configs/<algo>.yml``."""
    return CONFIG_DIR / f"{CONFIG_FILES.get(algo, algo)}.yml"


def conf_file_path(conf_file: str) -> Path:
    """``-conf``'s value as a path: an existing YAML file, or the name of a zoo config shipped in
    ``zoo_configs/`` (``ma2c_safe``: ``zoo_configs/ma2c_safe.yml``); a ValueError naming both otherwise."""
    if Path(conf_file).is_file():
        return Path(conf_file)
    shipped = sorted(path.stem for path in CONFIG_DIR.glob("*.yml"))
    if conf_file in shipped:
        return CONFIG_DIR / f"{conf_file}.yml"
    raise ValueError(f"{conf_file!r} is neither an existing YAML file nor a shipped zoo config: one of {shipped}.")


def algorithm_arguments(algo: str) -> list[str]:
    """Constructor arguments of the algorithm that a config may set."""
    return sorted(name for name in hyperparameters(get_algo(algo)) if name not in RESERVED_KEYS)


#: Actor-critic learners whose optimizer is SB3's default Adam (A2C's RMSprop and ACKTR's K-FAC
#: are configured by the algorithm itself).
ADAM_ACTOR_CRITICS = ("mappo", "matrpo")


def is_q_learning(algo: str) -> bool:
    """Whether the algorithm learns a Q-network (DQN-like: no separate critic to configure)."""
    return "exploration_fraction" in algorithm_arguments(algo)


#: Keys that may be a linear schedule ``lin_<initial value>`` (rl_zoo3's schedule strings).
SCHEDULE_KEYS = ("learning_rate", "clip_range", "clip_range_vf")
#: Value checks of the algorithms' common arguments: key -> (kind, lowest, highest, also allowed).
#: kind "int" accepts integers only, "float" any finite number; bounds are inclusive (the sizes
#: that allocate are bounded: a rollout or replay buffer of a valid config fits in memory).
VALUE_RANGES: dict[str, tuple[str, float | None, float | None, tuple]] = {
    "n_steps": ("int", 1, 100_000, ()),  # per slot: the rollout buffer holds n_steps x slots
    "batch_size": ("int", 1, 10_000_000, (None,)),
    "n_epochs": ("int", 1, 10_000, ()),
    "buffer_size": ("int", 1, 10_000_000, ()),  # transitions of the replay buffer
    "learning_starts": ("int", 0, None, ()),
    "train_freq": ("int", 1, None, ()),
    "gradient_steps": ("int", 1, 10_000, (-1,)),
    "target_update_interval": ("int", 1, None, ()),
    "stats_update_freq": ("int", 1, None, ()),
    "inverse_update_freq": ("int", 1, None, ()),
    "n_copies": ("int", 1, 256, (None,)),
    "learning_rate": ("float", 0, None, ()),
    "gamma": ("float", 0, 1, ()),
    "gae_lambda": ("float", 0, 1, ()),
    # a negative entropy coefficient penalises entropy: a sharper policy
    "ent_coef": ("float", None, None, ()),
    "vf_coef": ("float", 0, None, ()),
    "max_grad_norm": ("float", 0, None, ()),
    "rms_prop_eps": ("float", 0, None, ()),
    "clip_range": ("float", 0, None, ()),
    "clip_range_vf": ("float", 0, None, (None,)),
    "target_kl": ("float", 0, None, (None,)),
    "tau": ("float", 0, 1, ()),
    "exploration_fraction": ("float", 0, 1, ()),
    "exploration_initial_eps": ("float", 0, 1, ()),
    "exploration_final_eps": ("float", 0, 1, ()),
    "momentum": ("float", 0, 1, ()),
    "stat_decay": ("float", 0, 1, ()),
    "damping": ("float", 0, None, ()),
    "kl_clip": ("float", 0, None, ()),
}


def check_value(key: str, value: Any) -> None:
    """One hyperparameter's type and range (see :data:`VALUE_RANGES`; ``lin_<x>`` schedules for
    :data:`SCHEDULE_KEYS`): a ValueError naming the key, the value and what is expected."""
    if key not in VALUE_RANGES:
        return
    kind, lo, hi, also = VALUE_RANGES[key]
    if not isinstance(value, bool) and value in also:
        return
    if key in SCHEDULE_KEYS and isinstance(value, str) and value.startswith("lin_"):
        value = _number_or_none(value[4:])
    if kind == "int":
        ok, expected = is_integer(value), "an integer"
    else:
        ok, expected = is_number(value), "a finite number"
    bounds = "" if lo is None else f" >= {lo}"
    bounds += "" if hi is None else f" and <= {hi}"
    extra = "".join(f" or {allowed}" for allowed in also)
    extra += " (or a schedule lin_<initial value>)" if key in SCHEDULE_KEYS else ""
    if not ok or (lo is not None and value < lo) or (hi is not None and value > hi):
        raise ValueError(f"Invalid hyperparameter {key}={value!r}: expected {expected}{bounds}{extra}.")


def _number_or_none(text: str) -> float | str:
    try:
        return float(text)
    except ValueError:
        return f"lin_{text}"


#: Keys whose value rl-zoo accepts as a Python string (``policy_kwargs: "dict(net_arch=[64])"``):
#: parsed as literals here (:func:`sb3_marl.common.literals.parse_literal`), never evaluated.
LITERAL_KEYS = ("policy_kwargs", "replay_buffer_kwargs", "rollout_buffer_kwargs", "env_config")


def parse_string_values(hyperparams: dict[str, Any]) -> dict[str, Any]:
    """``hyperparams`` with the strings of :data:`LITERAL_KEYS` parsed as literals; a ValueError
    naming the key for code or for a value that is not a mapping."""
    from sb3_marl.common.literals import parse_literal

    parsed = dict(hyperparams)
    for key in LITERAL_KEYS:
        if isinstance(parsed.get(key), str):
            parsed[key] = parse_literal(parsed[key], key)
    for key in (*LITERAL_KEYS, "replay_buffer_class", "rollout_buffer_class"):
        if key in parsed and isinstance(parsed[key], str):
            raise ValueError(
                f"Invalid {key}={parsed[key]!r}: expected a mapping"
                + (
                    " of scenario config keys."
                    if key == "env_config"
                    else " (YAML or dict(...))."
                    if key in LITERAL_KEYS
                    else "; a class cannot be given as a string."
                )
            )
    return parsed


def validate_hyperparams(algo: str, hyperparams: dict[str, Any], env_id: str | None = None) -> None:
    """Unknown keys, an architecture or policy the algorithm cannot use, or (with ``env_id``) bad
    scenario keys and ``policy_kwargs`` the policy does not take: a ValueError naming the bad item
    and the valid ones."""
    allowed = algorithm_arguments(algo)
    valid = sorted({*allowed, *SCENARIO_KEYS, *ZOO_KEYS})
    unknown = sorted(set(hyperparams) - set(valid))
    if unknown:
        raise ValueError(f"Unknown hyperparameter(s) {unknown} for {algo!r}: valid keys are {valid}.")
    for key, value in hyperparams.items():
        check_value(key, value)
    # keys whose check lives beside the code that uses them (one check each)
    from sb3_marl.algos.a2c import check_cadence
    from sb3_marl.algos.common.rule_prior import RulePrior
    from sb3_marl.algos.common.teacher import check_safety_loss_coef

    prior = {key: value for key, value in hyperparams.items() if key in RulePrior().as_kwargs()}
    if prior:
        RulePrior.from_kwargs(prior)

    for key, check in (
        ("intervention_penalty", lambda value: check_penalty(value, "intervention_penalty")),
        ("supervisor_dropout", check_supervisor_dropout),
        ("safety_loss_coef", check_safety_loss_coef),
    ):
        if key in hyperparams:
            check(hyperparams[key])
    check_cadence(hyperparams.get("per_agent_updates", False), hyperparams.get("scale_lr_by_slots", False))
    masking = hyperparams.get("action_masking", True)
    if not isinstance(masking, bool):
        raise ValueError(
            f"Invalid action_masking={masking!r} for {algo!r}: expected true or false "
            "(True or False in a key:value on the command line)."
        )
    architecture = hyperparams.get("architecture", "default")
    q_learning = is_q_learning(algo)
    allowed_architectures = ["default", "shared"] if q_learning else ["default", *ARCHITECTURES]
    if architecture not in allowed_architectures:
        raise ValueError(
            f"Invalid architecture {architecture!r} for {algo!r}: expected one of {allowed_architectures}"
            + (" (a Q-network has no separate critic)." if q_learning else ".")
        )
    check_critic(algo, hyperparams)
    policy = hyperparams.get("policy", "MlpPolicy")
    aliases = sorted(get_algo(algo).policy_aliases)
    if policy not in aliases:
        raise ValueError(f"Invalid policy {policy!r} for {algo!r}: expected one of {aliases}.")
    if env_id is not None:
        validate_scenario(hyperparams, env_id)
        check_policy_kwargs(algo, hyperparams, env_id)


def check_critic(algo: str, hyperparams: dict[str, Any]) -> None:
    """``critic``: one of :data:`CRITICS`; ``centralised`` only for :data:`CENTRALISED_CRITIC_ALGOS`
    with ``architecture: separate`` (the critic has its own network on the global state)."""
    critic = hyperparams.get("critic", "local")
    if critic not in CRITICS:
        raise ValueError(f"Invalid critic={critic!r}: expected one of {list(CRITICS)}.")
    if critic == "local":
        return
    if algo not in CENTRALISED_CRITIC_ALGOS:
        raise ValueError(
            f"Invalid critic='centralised' for {algo!r}: a centralised critic is available for "
            f"{list(CENTRALISED_CRITIC_ALGOS[:3])}."
        )
    if hyperparams.get("architecture", "default") != "separate":
        raise ValueError(
            f"Invalid architecture={hyperparams.get('architecture', 'default')!r} with critic='centralised': "
            "expected 'separate' (the actor reads the AV's view, the critic the global state, each "
            "with its own network)."
        )
    if hyperparams.get("policy", "MlpPolicy") not in ("MlpPolicy", CENTRALISED_POLICY):
        raise ValueError(
            f"Invalid policy={hyperparams['policy']!r} with critic='centralised': expected "
            f"'MlpPolicy' or {CENTRALISED_POLICY!r} (the centralised critic sets the policy)."
        )


def is_centralised(hyperparams: dict[str, Any]) -> bool:
    """Whether the entry trains a centralised critic (``critic: centralised``)."""
    return hyperparams.get("critic", "local") == "centralised"


def policy_for(hyperparams: dict[str, Any]) -> str:
    """The policy alias of an entry: :data:`CENTRALISED_POLICY` with ``critic: centralised``."""
    if is_centralised(hyperparams):
        return CENTRALISED_POLICY
    return str(hyperparams.get("policy", "MlpPolicy"))


def check_policy_kwargs(algo: str, hyperparams: dict[str, Any], env_id: str) -> None:
    """``policy_kwargs`` (with the architecture's preset) must build the policy on the scenario's
    per-AV spaces: a ValueError naming ``policy_kwargs`` otherwise (before any folder or env)."""
    from gymnasium import spaces

    from sb3_marl.envs.observation import centralised_observation_space, observation_space

    kwargs = hyperparams.get("policy_kwargs")
    if kwargs is not None and not isinstance(kwargs, dict):
        raise ValueError(f"Invalid policy_kwargs={kwargs!r}: expected a mapping, e.g. dict(net_arch=[64, 64]).")
    check_network_size(kwargs, "Invalid policy_kwargs")
    density = (gym.spec(env_id).kwargs or {}).get("density", 1)
    defaults = scenario_default_config(scenario_of(env_id))
    config = {**defaults, "density": density, **(hyperparams.get("env_config") or {}), "n_avs": 1}
    per_av = observation_space(1, config)
    box = spaces.Box(per_av.low[0], per_av.high[0], dtype=per_av.dtype)  # type: ignore[arg-type]
    obs_space: spaces.Space = box
    if is_centralised(hyperparams):
        obs_space = centralised_observation_space(box, max(av_counts(env_id, hyperparams.get("env_config"))))
    policy_class = get_algo(algo).policy_aliases[policy_for(hyperparams)]  # validated by validate_hyperparams
    try:
        policy_class(obs_space, spaces.Discrete(5), lambda _: 1e-3, **policy_kwargs_for(algo, hyperparams))
    except Exception as error:  # TypeError (unknown keyword), RuntimeError / ValueError (bad sizes), ...
        raise ValueError(
            f"Invalid policy_kwargs={kwargs!r} for {algo!r}: the policy cannot be built with it "
            f"({type(error).__name__}: {error})."
        ) from None


def validate_scenario(hyperparams: dict[str, Any], env_id: str) -> None:
    """The scenario keys of an entry for ``env_id``: reward mode, copies, reward scale, env config."""
    check_sharing_options(hyperparams.get("reward_mode", "local"), hyperparams.get("n_copies"))
    check_reward_scale(hyperparams.get("reward_scale", 1.0), "reward_scale")
    stored = hyperparams.get("stored_actions", "proposed")
    if stored not in STORED_ACTIONS:
        raise ValueError(f"Invalid stored_actions={stored!r}: expected one of {list(STORED_ACTIONS)}.")
    env_config = hyperparams.get("env_config", {})
    if not isinstance(env_config, dict):
        raise ValueError(f"Invalid env_config={env_config!r}: expected a mapping of scenario config keys.")
    scenario = scenario_of(env_id)
    density = (gym.spec(env_id).kwargs or {}).get("density", 1)
    validate_config({**scenario_default_config(scenario), "density": density, **env_config}, scenario)


def policy_kwargs_for(algo: str, hyperparams: dict[str, Any]) -> dict[str, Any]:
    """``policy_kwargs`` with the MA2C network of ``architecture`` merged in."""
    kwargs = dict(hyperparams.get("policy_kwargs") or {})
    architecture = hyperparams.get("architecture", "default")
    if architecture == "default":
        return kwargs
    preset = ma2c_q_policy_kwargs() if is_q_learning(algo) else ma2c_policy_kwargs(architecture)
    if is_centralised(hyperparams):
        preset["features_extractor_class"] = LocalViewExtractor
    if algo in ADAM_ACTOR_CRITICS:
        preset["optimizer_kwargs"] = dict(ACTOR_CRITIC_FUSED_ADAM)
    return {**preset, **kwargs}
