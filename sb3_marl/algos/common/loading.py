"""Loading model zips that others share as data, never as code.

- **Model zips.** SB3 stores some entries of a model's ``data`` with cloudpickle; unpickling a
  zip from the internet runs whatever code it carries. :func:`safe_custom_objects` rebuilds every
  serialized entry from its readable fields and what the project knows (the algorithm's policy
  and buffer classes, gymnasium spaces, SB3 schedules, an allow-list of torch classes) and hands
  them to SB3's loader as ``custom_objects``, which then unpickles nothing; tensors are read with
  ``torch.load(weights_only=True)`` (SB3's default). An entry that cannot be rebuilt, and a
  ``.pth`` member holding a pickled object where tensors belong (:func:`check_plain_tensors`),
  refuse the load with a one-line :class:`UnsafeModelError` naming it. ``trust_remote_code=True``
  (the Hugging Face convention) loads a zip from another tool the way SB3 does, unpickling its
  ``data`` entries, with a warning (its tensors are still read as data only).

The other data others share: run-folder YAML (:func:`sb3_marl.common.files.read_run_yaml`) and strings of
hyperparameters (:func:`sb3_marl.common.literals.parse_literal`, whose :data:`~sb3_marl.common.literals.ALLOWED_NAMES`
are also the torch classes a zip's ``policy_kwargs`` may name).
"""

from __future__ import annotations

import ast
import inspect
import json
import re
import warnings
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.utils import ConstantSchedule, FloatSchedule, LinearSchedule

from sb3_marl.common.literals import ALLOWED_NAMES


class UnsafeModelError(ValueError):
    """A model zip has a serialized entry that cannot be rebuilt without running its code."""


# ---- model zips --------------------------------------------------------------------------------


#: Bounds of a model zip's members once inflated [bytes]: its ``data`` JSON, and each other member
#: (the policy's and optimiser's tensors: a paper network's are 0.1 MB).
MAX_DATA_BYTES, MAX_MEMBER_BYTES = 10_000_000, 500_000_000


def read_model_data(path: str | Path) -> dict[str, Any]:
    """The ``data`` JSON of an SB3 model zip as written (serialized entries unread); a ValueError
    naming the file if it is not a readable SB3 zip."""
    try:
        with zipfile.ZipFile(path) as archive:
            for member in archive.infolist():  # sizes as declared, which bound what zipfile reads
                limit = MAX_DATA_BYTES if member.filename == "data" else MAX_MEMBER_BYTES
                if member.file_size > limit:
                    raise ValueError(f"member {member.filename!r} inflates to {member.file_size:,} bytes (at most {limit:,})")
            data = json.loads(archive.read("data"))
    except Exception as error:  # zipfile alone raises BadZipFile, NotImplementedError, RuntimeError, EOFError, ...
        raise ValueError(f"{path} is not a readable SB3 model file ({type(error).__name__}: {error}).") from None
    if not isinstance(data, dict) or not data:
        raise ValueError(f"{path} is not a readable SB3 model file (no data).")
    return data


def is_serialized(entry: Any) -> bool:
    return isinstance(entry, dict) and ":serialized:" in entry


#: Serialized entries that hold training state only; loading starts them afresh (SB3's ``learn``
#: resets the env and the episode buffers when they are None).
TRANSIENT = ("_last_obs", "_last_episode_starts", "_last_original_obs", "ep_info_buffer", "ep_success_buffer")


def safe_custom_objects(algo_class: Any, path: str | Path) -> dict[str, Any]:
    """Every serialized entry of the zip's data rebuilt without unpickling (see module doc).

    :raises UnsafeModelError: naming the first entry that cannot be rebuilt
    """
    data = read_model_data(path)
    rebuilt: dict[str, Any] = {}
    for key, entry in data.items():
        if is_serialized(entry):
            try:
                rebuilt[key] = _rebuild(key, entry, algo_class)
            except (ValueError, KeyError, TypeError) as error:
                raise UnsafeModelError(
                    f"{path}: the entry {key!r} of its data is pickled code that sb3-marl cannot rebuild from "
                    f"plain data ({error}); it was not loaded. If you trust this file and its source, load it with "
                    "trust_remote_code=True (command line: --trust-remote-code)."
                ) from None
    return rebuilt


def _class_name(text: str) -> str:
    """``"<class 'a.b.C'>"`` -> ``"a.b.C"``."""
    match = re.fullmatch(r"<class '([\w.]+)'>", text)
    if match is None:
        raise ValueError(f"{text!r} is not a class")
    return match.group(1)


def _rebuild(key: str, entry: dict[str, Any], algo_class: Any) -> Any:
    kind = _class_name(entry[":type:"])
    if key in TRANSIENT:
        return None
    if kind.endswith(("utils.ConstantSchedule", "utils.FloatSchedule", "utils.LinearSchedule")):
        return _schedule(kind.rpartition(".")[2], entry)
    if kind == "gymnasium.spaces.box.Box":
        shape = tuple(int(n) for n in entry["_shape"])
        dtype = np.dtype(entry["dtype"])
        low, high = (_numbers(entry[bound], shape).astype(dtype) for bound in ("low", "high"))
        return spaces.Box(low, high, shape, dtype)
    if kind == "gymnasium.spaces.dict.Dict":
        return _dict_space(entry["spaces"])
    if kind == "gymnasium.spaces.discrete.Discrete":
        return spaces.Discrete(int(entry["n"]), start=int(entry["start"]))
    if kind == "dict" and key == "policy_kwargs":
        return {
            name: _plain_value(f"policy_kwargs.{name}", text, algo_class)
            for name, text in entry.items()
            if name not in (":type:", ":serialized:")
        }
    if kind == "stable_baselines3.common.type_aliases.TrainFreq":
        # not readable: the algorithm's default (continuing training passes the run's own value)
        return next(
            parameter.default
            for klass in algo_class.__mro__
            if (parameter := inspect.signature(klass).parameters.get("train_freq")) is not None
        )
    if kind in ("abc.ABCMeta", "type"):
        return _known_class(key, entry, algo_class)
    raise ValueError(f"type {kind} is not one sb3-marl rebuilds")


#: A Box of uniform bounds as gymnasium prints it: ``Box(-1.0, 1.0, (5, 5), float32)``.
UNIFORM_BOX = r"Box\(([-+\w.]+), ([-+\w.]+), \(([\d, ]*)\), (\w+)\)"


def _dict_space(text: str) -> spaces.Dict:
    """A Dict space of uniform-bound Boxes from its printed ``spaces`` (the centralised critic's)."""
    items = re.findall(rf"'(\w+)': {UNIFORM_BOX}", text)
    if not items or len(items) != text.count("Box("):
        raise ValueError(f"the Dict space {text[:80]!r} is not made of readable Boxes of uniform bounds")
    return spaces.Dict(
        {
            name: spaces.Box(
                float(low), float(high), tuple(int(n) for n in shape.replace(" ", "").split(",") if n), np.dtype(dtype)
            )
            for name, low, high, shape, dtype in items
        }
    )


def _numbers(text: str, shape: tuple[int, ...]) -> np.ndarray:
    """A numpy array printed as ``text`` (numbers, inf, nan), of ``shape``."""
    values = re.findall(r"[-+]?(?:inf|nan|\d+\.?\d*(?:e[-+]?\d+)?)", text)
    if "..." in text or len(values) != int(np.prod(shape)):
        raise ValueError(f"the bounds {text[:40]!r} are not a readable array of shape {shape}")
    return np.array([float(v) for v in values]).reshape(shape)


def _schedule(kind: str, entry: dict[str, Any]) -> Any:
    if kind == "ConstantSchedule":
        return ConstantSchedule(float(entry["val"]))
    if kind == "LinearSchedule":
        return LinearSchedule(float(entry["start"]), float(entry["end"]), float(entry["end_fraction"]))
    inner = re.fullmatch(r"(\w+)\((.*)\)", entry["value_schedule"])
    if inner is None or inner.group(1) not in ("ConstantSchedule", "LinearSchedule"):
        raise ValueError(f"schedule {entry['value_schedule']!r} is not a constant or linear one")
    fields = dict(item.split("=") for item in inner.group(2).split(", "))
    return FloatSchedule(_schedule(inner.group(1), fields))


#: Where the classes a zip may name lived before (module prefix now -> modules then): every
#: learner and buffer in ``sb3_marl.algos.masking`` until 2026-12, the buffers in
#: ``sb3_marl.algos.buffers`` and the policies in ``sb3_marl.policies`` until the layered packages.
LEGACY_MODULES: dict[str, tuple[str, ...]] = {
    "sb3_marl.algos.": ("sb3_marl.algos.masking",),
    "sb3_marl.algos.common.buffers": ("sb3_marl.algos.buffers",),
    "sb3_marl.algos.common.policies": ("sb3_marl.policies",),
}


def _known_classes(algo_class: Any) -> dict[str, type]:
    """Classes a model of ``algo_class`` may name: its policies, SB3's and sb3-contrib's buffers, our
    feature extractors, and the classes the learner declares (``known_classes``: its own buffers).
    Classes are also known under the modules that held them before (:data:`LEGACY_MODULES`: zips
    saved then name those)."""
    from sb3_contrib.common.maskable.buffers import MaskableDictRolloutBuffer, MaskableRolloutBuffer
    from stable_baselines3.common.buffers import ReplayBuffer, RolloutBuffer

    from sb3_marl.algos.common.policies import GlobalStateExtractor, LocalViewExtractor, MA2CFeaturesExtractor

    classes = [
        *algo_class.policy_aliases.values(),
        MaskableRolloutBuffer,
        MaskableDictRolloutBuffer,
        RolloutBuffer,
        ReplayBuffer,
        MA2CFeaturesExtractor,
        LocalViewExtractor,
        GlobalStateExtractor,
        *getattr(algo_class, "known_classes", ()),
    ]
    known = {f"{c.__module__}.{c.__qualname__}": c for c in classes}
    legacy = {
        f"{old}.{c.__qualname__}": c
        for c in classes
        for prefix, olds in LEGACY_MODULES.items()
        if c.__module__.startswith(prefix)
        for old in olds
    }
    return {**legacy, **known}


def saved_policy_class(data: dict[str, Any], algo_class: Any) -> type | None:
    """The policy class a model's ``data`` names, among ``algo_class``'s; None if it names none
    of them (a model of another algorithm or tool)."""
    entry = data.get("policy_class")
    try:
        return _known_class("policy_class", entry, algo_class) if is_serialized(entry) else None
    except (ValueError, KeyError):
        return None


def _known_class(key: str, entry: Any, algo_class: Any) -> type:
    """A class entry (``policy_class``, ``rollout_buffer_class``, ...) from its module and the name
    its methods carry (``<function NAME.method at ...>``), among :func:`_known_classes`."""
    names = {
        m.group(1) for text in entry.values() if isinstance(text, str) for m in [re.match(r"<function (\w+)\.", text)] if m
    }
    known = _known_classes(algo_class)
    matches = [known[f"{entry['__module__']}.{name}"] for name in names if f"{entry['__module__']}.{name}" in known]
    if len(matches) != 1:
        raise ValueError(f"class {entry.get('__module__')}.{'/'.join(sorted(names)) or '?'} is not one of {sorted(known)}")
    return matches[0]


def _plain_value(key: str, text: Any, algo_class: Any) -> Any:
    """One readable value of a serialized dict: a JSON value, a known class, or a literal."""
    if not isinstance(text, str):
        return text
    if text.startswith("<class "):
        name = _class_name(text)
        classes = {
            **{f"{c.__module__}.{c.__qualname__}": c for c in ALLOWED_NAMES.values() if isinstance(c, type)},
            **_known_classes(algo_class),
        }
        if name not in classes:
            raise ValueError(f"{key} is the class {name}, not one of {sorted(classes)}")
        return classes[name]
    try:
        return ast.literal_eval(text)
    except (ValueError, SyntaxError):
        raise ValueError(f"{key}={text!r} is not a literal") from None


def load_model(
    algo_class: Any,
    path: str | Path,
    *,
    trust_remote_code: bool = False,
    custom_objects: dict[str, Any] | None = None,
    **kwargs: Any,
) -> Any:
    """``algo_class.load(path, ...)`` (SB3's own loader) with every serialized entry rebuilt as
    data (:func:`safe_custom_objects`); with ``trust_remote_code`` the zip is unpickled as SB3
    does, after a warning naming the file."""
    if trust_remote_code:
        warnings.warn(
            f"Loading {path} with trust_remote_code=True: its pickled entries are unpickled and may run code.", stacklevel=3
        )
        objects = dict(custom_objects or {})
    else:
        from sb3_marl.algos.common.policies import check_network_size

        objects = {**safe_custom_objects(algo_class, path), **(custom_objects or {})}
        check_network_size(objects.get("policy_kwargs"), str(path))
    from stable_baselines3.common.base_class import BaseAlgorithm

    try:
        model = BaseAlgorithm.load.__func__(algo_class, path, custom_objects=objects, **kwargs)  # type: ignore[attr-defined]  # SB3's own loader
    except Exception:
        check_plain_tensors(path)
        raise
    check_finite_weights(model, path)
    return model


def check_plain_tensors(path: str | Path) -> None:
    """An :class:`UnsafeModelError` naming the first ``.pth`` member of the zip at ``path`` (the
    policy's and optimiser's tensors, ``pytorch_variables.pth``) that holds a pickled object where
    plain tensors belong, in one line; ``torch.load(weights_only=True)`` refuses to unpickle it, so
    nothing of it runs, with or without ``trust_remote_code``. Members that are unreadable for other
    reasons (truncated, not a torch file) and an unreadable zip are left to SB3's loader to report."""
    import pickle

    import torch

    try:
        archive = zipfile.ZipFile(path)
    except Exception:  # not a zip: SB3's loader says so
        return
    with archive:
        for name in archive.namelist():
            if not name.endswith(".pth") or archive.getinfo(name).file_size > MAX_MEMBER_BYTES:
                continue
            try:
                with archive.open(name) as member:
                    torch.load(member, map_location="cpu", weights_only=True)
            except pickle.UnpicklingError as error:  # torch's refusal of a global it does not allow
                named = re.search(r"GLOBAL (\S+) was not an allowed global", str(error))
                detail = f": it names {named.group(1)}" if named else ""
                raise UnsafeModelError(
                    f"{path}: {name}: not plain tensors (a pickled object where weights belong{detail}); "
                    "refused without running it."
                ) from None
            except Exception:  # truncated or not a torch file: SB3's loader reports it
                continue


def check_finite_weights(model: Any, path: str | Path) -> None:
    """A ValueError naming ``path`` and the first tensor if any weight of ``model``'s policy is NaN
    or infinite (a run that diverged: every action it would take is meaningless)."""
    from sb3_marl.algos.common.policies import non_finite_weights

    name = non_finite_weights(model.policy)
    if name is not None:
        raise ValueError(
            f"{path}: the model's weights {name} are not finite (NaN or inf): its training diverged; "
            "it is not used (retrain, e.g. with a smaller learning rate or loss weights)."
        )


def _safe_load(
    cls: Any,
    path: Any,
    env: Any = None,
    device: Any = "auto",
    custom_objects: dict[str, Any] | None = None,
    print_system_info: bool = False,
    force_reset: bool = True,
    trust_remote_code: bool = False,
    **kwargs: Any,
) -> Any:
    return load_model(
        cls,
        path,
        trust_remote_code=trust_remote_code,
        custom_objects=custom_objects,
        env=env,
        device=device,
        print_system_info=print_system_info,
        force_reset=force_reset,
        **kwargs,
    )


#: ``load`` of every registered learner (``load = safe_load`` in its class body): SB3's arguments
#: plus ``trust_remote_code``, through :func:`load_model` (no unpickling unless it is True). A
#: learner's ``known_classes`` names its own classes its zips may name (its buffers).
safe_load = classmethod(_safe_load)


__all__ = [
    "UnsafeModelError",
    "check_finite_weights",
    "check_plain_tensors",
    "load_model",
    "read_model_data",
    "safe_custom_objects",
    "safe_load",
    "saved_policy_class",
]
