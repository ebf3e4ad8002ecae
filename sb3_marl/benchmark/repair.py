"""A grid checks what it calls finished, and repairs a damaged trial by running it again.

A trial is *finished* when its ``result.json``, ``trial.json``, its run's ``evaluations.npz`` and
its final model zip all read back through the project's readers (:func:`trial_damage`): the JSON
files checked field by field, the npz's arrays read, the zip's ``data`` entry read and every member
inflated with its CRC checked (the model is not built). A checkpoint *loads* when its
``state.json``, ``model.zip``, ``evaluations.npz`` and replay buffer read back the same way
(:func:`checkpoint_damage`).

Before a local grid runs, the launcher repairs each trial it is to run (:func:`repair_trial`): a
damaged file is moved aside to ``<name>.damaged`` (never deleted), the readable ``result.json`` of a
trial re-run for another damaged file to ``result.json.superseded``, and the trial runs again from its
newest checkpoint that loads (its ``checkpoint/``, the previous one a kill left between two renames,
else the newest of Ray's copies under ``ray/``) or from the start. A trial checks its checkpoint
again when it starts (:func:`restore_checkpoint`; Ray's restarts, grids in a storage URI).
"""

from __future__ import annotations

import shutil
import zipfile
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rl_zoo3.utils import EnvironmentName

from sb3_marl.algos.common.loading import read_model_data
from sb3_marl.benchmark.grid import TrialSpec
from sb3_marl.benchmark.trial_files import (
    CHECKPOINT,
    PREVIOUS_CHECKPOINT,
    RESULT,
    RUN_ID,
    TRIAL,
    checked_evaluations,
    checked_result,
    checkpoint_timesteps,
    read_trial_info,
    trial_folder,
)
from sb3_marl.common.files import REPLAY_BUFFER_FILE, inside, npz_headers, read_json_object

#: The suffix of a damaged file moved aside, and of a readable ``result.json`` of a trial re-run.
DAMAGED, SUPERSEDED = ".damaged", ".superseded"


def check_zip(path: Path) -> None:
    """Inflate every member of the zip at ``path`` and check its CRC (as far as its declared size);
    a ValueError naming the file and what is wrong."""
    try:
        with zipfile.ZipFile(path) as archive:
            bad = archive.testzip()
    except Exception as error:  # zipfile raises BadZipFile, EOFError, OSError, zlib.error, ...
        raise ValueError(f"{path} is not a readable zip ({type(error).__name__}: {error}).") from None
    if bad is not None:
        raise ValueError(f"{path}: its member {bad!r} is corrupt (CRC mismatch).")


def check_model(path: Path) -> None:
    """An SB3 model zip that reads back: its ``data`` (:func:`read_model_data`, members' sizes
    bounded) and every member's bytes (:func:`check_zip`); nothing is unpickled or built."""
    read_model_data(path)
    check_zip(path)


def check_replay_buffer(path: Path) -> None:
    """A checkpoint's ``replay_buffer.npz`` that reads back: plain arrays (:func:`npz_headers`), every byte."""
    npz_headers(path)
    check_zip(path)


def _check_result(path: Path) -> None:
    final = checked_result(read_json_object(path))
    float(final["return_mean"])  # what status shows of a finished trial


def trial_damage(log_folder: Path, spec: TrialSpec) -> dict[Path, str]:
    """The damaged files of ``spec``'s trial in ``log_folder``, each with why, in one line: of a
    finished one (with ``result.json``) every file it needs, of another its ``trial.json`` (if any),
    which its next attempt reads. {} if none is damaged."""
    folder = trial_folder(log_folder, spec)
    run = folder / spec.algo / f"{EnvironmentName(spec.env_id)}_{RUN_ID}"

    def same_trial(path: Path) -> None:
        if read_trial_info(path)["trial"] != spec.to_dict():
            raise ValueError(f"{path} is not {spec.trial_id}'s")

    files: dict[Path, Callable[[Path], Any]] = {
        folder / RESULT: _check_result,
        folder / TRIAL: same_trial,
        run / "evaluations.npz": checked_evaluations,
        run / f"{EnvironmentName(spec.env_id)}.zip": check_model,
    }
    if not (folder / RESULT).exists():
        files = {folder / TRIAL: same_trial} if (folder / TRIAL).exists() else {}
    return _damage(files, Path(log_folder))


def checkpoint_damage(checkpoint: Path, root: Path, whole: bool = True) -> dict[Path, str]:
    """The damaged files of the checkpoint folder ``checkpoint`` (in ``root``, which no link may leave),
    each with why; with ``whole`` False only its ``state.json`` (a storage grid's local copy keeps
    no other file). {} if it loads."""
    files: dict[Path, Callable[[Path], Any]] = {checkpoint / "state.json": lambda path: checkpoint_timesteps(path.parent)}
    if whole:
        files.update({checkpoint / "model.zip": check_model, checkpoint / "evaluations.npz": checked_evaluations})
        if (checkpoint / REPLAY_BUFFER_FILE).exists():
            files[checkpoint / REPLAY_BUFFER_FILE] = check_replay_buffer
    return _damage(files, root)


def _damage(files: dict[Path, Callable[[Path], Any]], root: Path) -> dict[Path, str]:
    """Each of ``files`` that is missing or that its reader refuses, with why."""
    damage = {}
    for path, read in files.items():
        try:
            if not path.is_file():
                raise FileNotFoundError(f"{path} is missing")
            read(inside(path, root))
        except (OSError, ValueError, KeyError, TypeError, AttributeError, ArithmeticError) as error:
            damage[path] = f"{type(error).__name__}: {error}"
    return damage


def move_aside(path: Path, suffix: str = DAMAGED) -> Path:
    """Rename the file or folder ``path`` to ``<name><suffix>`` (``-2``, ``-3``, ... added where that
    is taken); the new path."""
    target, number = path.with_name(path.name + suffix), 1
    while target.exists() or target.is_symlink():
        number += 1
        target = path.with_name(f"{path.name}{suffix}-{number}")
    path.rename(target)
    return target


@dataclass
class Restored:
    """Where a trial continues from: ``timesteps`` AV-steps (0: the start) of ``source`` (its
    ``checkpoint/``, or Ray's copy of it), and the damaged files found on the way, moved aside."""

    timesteps: int = 0
    source: str = ""
    damaged: list[str] = field(default_factory=list)

    def plan(self) -> str:
        """``re-run from its checkpoint at N AV-steps`` or ``re-run from the start``."""
        return f"re-run from {self.source} at {self.timesteps:,} AV-steps" if self.timesteps else "re-run from the start"

    def summary(self) -> str:
        """The damaged files and the plan, in one line."""
        return "; ".join([*self.damaged, self.plan()])


def restore_checkpoint(folder: Path, copies: Iterable[Path] = ()) -> Restored:
    """Make ``<folder>/checkpoint`` the trial's newest checkpoint that loads: its own, else the
    previous one that a kill left between two renames, else the one with the most AV-steps of
    ``copies`` (Ray's, copied in). A damaged checkpoint of the trial is moved aside to
    ``<name>.damaged``; none that loads: the trial starts over."""
    checkpoint, restored = folder / CHECKPOINT, Restored()
    for candidate in (checkpoint, folder / PREVIOUS_CHECKPOINT):
        if not candidate.is_dir():
            continue
        damage = checkpoint_damage(candidate, folder)
        if not damage:
            if candidate != checkpoint:
                candidate.rename(checkpoint)
            restored.timesteps, restored.source = checkpoint_timesteps(checkpoint), "its checkpoint"
            return restored
        found = ", ".join(describe(path, why, folder) for path, why in damage.items())
        restored.damaged.append(f"{found}: {candidate.name}/ moved aside to {move_aside(candidate).name}/")
    loadable = [copy for copy in copies if copy.is_dir() and not checkpoint_damage(copy, copy.parent)]
    if loadable:
        timesteps, best = max((checkpoint_timesteps(copy), copy) for copy in loadable)
        shutil.copytree(best, checkpoint)
        restored.timesteps, restored.source = timesteps, f"Ray's copy of its checkpoint ({best.parent.parent.name})"
    return restored


def describe(path: Path, why: str, folder: Path) -> str:
    """``<path in folder> unreadable (<why>)`` without the folder's name repeated (``missing``: missing)."""
    relative = path.relative_to(folder).as_posix()
    if why.startswith("FileNotFoundError: "):
        return f"{relative} missing"
    return f"{relative} unreadable ({why.removeprefix('ValueError: ').replace(f'{folder}/', '').rstrip('.')})"


def repair_trial(log_folder: Path, spec: TrialSpec) -> str | None:
    """Repair ``spec``'s trial in ``log_folder`` before it runs (the launcher holding the folder's lock):
    move its damaged files aside (:func:`trial_damage`), and a readable ``result.json`` too where
    another file is damaged (the trial is re-run), and put its newest checkpoint that loads in
    place (:func:`restore_checkpoint`, Ray's copies under ``ray/`` included). Returns what was
    found and done as one line (``trial X: result.json unreadable (...): re-run from its checkpoint
    at N AV-steps``), None if nothing was damaged and the trial continues from its own checkpoint."""
    folder = trial_folder(log_folder, spec)
    damage = trial_damage(log_folder, spec)
    found = [
        describe(path, why, folder) + (f": moved aside to {move_aside(path).name}" if path.exists() else "")
        for path, why in damage.items()
    ]
    if damage and (folder / RESULT).exists():
        found.append(f"{RESULT} moved aside to {move_aside(folder / RESULT, SUPERSEDED).name}")
    copies = sorted(Path(log_folder).glob(f"ray/*/{spec.trial_id}/checkpoint_*"))
    restored = restore_checkpoint(folder, copies) if folder.is_dir() else Restored()
    restored.damaged[:0] = found
    if not restored.damaged and not restored.source.startswith("Ray's"):
        return None
    return f"trial {spec.trial_id}: {restored.summary()}"


__all__ = [
    "DAMAGED",
    "Restored",
    "check_model",
    "checkpoint_damage",
    "move_aside",
    "repair_trial",
    "restore_checkpoint",
    "trial_damage",
]
