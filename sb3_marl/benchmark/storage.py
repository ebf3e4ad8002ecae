"""A grid's storage as a URI (``--storage``), for clusters whose nodes share no disk: ``s3://``,
``gs://``, ``file://`` or any file system pyarrow resolves from a URI, as Ray Tune's
``storage_path`` does. Credentials and endpoints come from the environment and the cloud SDKs'
usual places (``AWS_ACCESS_KEY_ID``, ``AWS_ENDPOINT_URL``, ...); nothing here writes them anywhere.

Layout under the URI, the log folder's (:mod:`~sb3_marl.benchmark.runner`)::

    benchmark.json
    trials/<trial id>/                 the trial folder, its checkpoint's step count (``checkpoint/state.json``)
    trials/<trial id>/checkpoints/<n>/ the checkpoint at n AV-steps (``state.json`` uploaded last)
    ray/                               Ray Tune's experiment state

Each trial works in a node-local folder: when it starts it downloads its trial folder and its
latest whole checkpoint (a trial that Ray restarts on another node after its node died continues
from there, with its evaluation history); after every checkpoint it uploads the checkpoint, then
the trial folder; at the end the trial folder, ``result.json`` last. ``status``, ``report`` and
``evaluate`` download the trial folders (without the checkpoints) into the local ``-f`` folder.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path, PurePosixPath
from typing import Any

from sb3_marl.common.files import MAX_JSON_BYTES, json_object

#: What a trial folder's upload keeps of its checkpoint (the checkpoint goes to ``checkpoints/<n>/``).
CHECKPOINT_KEPT = "checkpoint/state.json"
CHECKPOINTS = "checkpoints"
#: The largest file a download takes [bytes] (a trial's model zips are about 0.5 MB, its
#: TensorBoard logs kilobytes).
MAX_FILE_BYTES = 200_000_000


class GridStorage:
    """The grid at ``uri``: its file system (pyarrow's) and its root path there.

    :raises ValueError: naming ``--storage`` when pyarrow resolves no file system from ``uri``
    """

    def __init__(self, uri: str) -> None:
        from pyarrow import fs

        self.uri = uri.rstrip("/")
        if "://" not in self.uri:
            raise ValueError(f"--storage {uri!r}: expected a URI such as s3://bucket/grid, gs://bucket/grid or file:///path.")
        try:
            self.fs, root = fs.FileSystem.from_uri(self.uri)
        except (OSError, ValueError) as error:
            raise ValueError(f"--storage {uri!r}: no file system for this URI ({error}).") from None
        self.root = PurePosixPath(root)
        self.sync_s, self.bytes = 0.0, 0  # [s] spent in and bytes moved by uploads and downloads
        self._sent: dict[Path, tuple[int, int]] = {}  # local file -> (size, mtime) at its last upload
        #: trial id -> its result.json's :meth:`stamp` when its files last read back whole (the
        #: launcher's check, :func:`~sb3_marl.benchmark.runner._finished`, downloads a trial once)
        self.found_whole: dict[str, tuple[int, int | None]] = {}

    @property
    def ray_path(self) -> str:
        """Ray Tune's ``storage_path``: ``<uri>/ray``."""
        return f"{self.uri}/ray"

    def _path(self, relative: str) -> str:
        return str(self.root / relative)

    def exists(self, relative: str) -> bool:
        """Whether the file ``relative`` (to the grid's root) is in the storage."""
        from pyarrow import fs

        return self.fs.get_file_info(self._path(relative)).type == fs.FileType.File

    def stamp(self, relative: str) -> tuple[int, int | None] | None:
        """(size [bytes], modification time [ns] where the file system keeps one) of the file
        ``relative``, None if it is not in the storage."""
        from pyarrow import fs

        info = self.fs.get_file_info(self._path(relative))
        return (info.size, info.mtime_ns) if info.type == fs.FileType.File else None

    def read_json_object(self, relative: str) -> dict[str, Any] | None:
        """The JSON object in the file ``relative`` (at most :data:`MAX_JSON_BYTES`), None if absent;
        a ValueError naming it otherwise (:func:`~sb3_marl.common.files.json_object`)."""
        from pyarrow import fs

        info = self.fs.get_file_info(self._path(relative))
        if info.type != fs.FileType.File:
            return None
        name = f"{self.uri}/{relative}"
        if info.size > MAX_JSON_BYTES:
            raise ValueError(f"{name}: {info.size:,} bytes, more than the {MAX_JSON_BYTES:,} a JSON file may have.")
        with self.fs.open_input_stream(info.path) as stream:
            return json_object(stream.read(), name)

    def write_text(self, relative: str, text: str) -> None:
        """Write ``relative`` (an object store's write replaces the object whole)."""
        self.fs.create_dir(str(PurePosixPath(self._path(relative)).parent), recursive=True)
        with self.fs.open_output_stream(self._path(relative)) as stream:
            stream.write(text.encode("utf-8"))

    def upload_trial(self, folder: Path, last: str | None = None) -> None:
        """Upload the trial folder ``folder`` to ``trials/<its name>/`` (see :data:`CHECKPOINT_KEPT`),
        the file ``last`` (relative to ``folder``) after every other; a file unchanged (size and
        modification time) since this object uploaded it is not sent again."""
        files = sorted(_uploaded(folder), key=lambda path: path.relative_to(folder).as_posix() == last)
        for path in files:
            stat = path.stat()
            if self._sent.get(path) == (stat.st_size, stat.st_mtime_ns):
                continue
            self._sent[path] = (stat.st_size, stat.st_mtime_ns)
            target = self._path(f"trials/{folder.name}/{path.relative_to(folder).as_posix()}")
            self.fs.create_dir(str(PurePosixPath(target).parent), recursive=True)
            self._copy(path, target)

    def upload_checkpoint(self, checkpoint: Path, trial_id: str, timesteps: int) -> None:
        """Upload the checkpoint folder ``checkpoint`` (written at ``timesteps`` AV-steps) to
        ``trials/<trial_id>/checkpoints/<timesteps>/``, its ``state.json`` last (a checkpoint is whole
        once it has one), then delete the trial's earlier checkpoints."""
        prefix = f"trials/{trial_id}/{CHECKPOINTS}"
        self.fs.create_dir(self._path(f"{prefix}/{timesteps}"), recursive=True)
        files = sorted((p for p in checkpoint.iterdir() if p.is_file()), key=lambda p: p.name == "state.json")
        for path in files:
            self._copy(path, self._path(f"{prefix}/{timesteps}/{path.name}"))
        for older in self._checkpoints(trial_id):
            if older != timesteps:
                self.fs.delete_dir(self._path(f"{prefix}/{older}"))

    def _checkpoints(self, trial_id: str) -> list[int]:
        """The AV-steps of the trial's checkpoints in the storage, whole or not."""
        from pyarrow import fs

        selector = fs.FileSelector(self._path(f"trials/{trial_id}/{CHECKPOINTS}"), allow_not_found=True)
        names = [PurePosixPath(info.path).name for info in self.fs.get_file_info(selector)]
        return sorted(int(name) for name in names if name.isdigit())

    def download_checkpoint(self, trial_id: str, target: Path) -> int:
        """The trial's latest whole checkpoint into ``target`` (replaced); its AV-steps, 0 if none."""
        from pyarrow import fs

        for timesteps in reversed(self._checkpoints(trial_id)):
            source = self._path(f"trials/{trial_id}/{CHECKPOINTS}/{timesteps}")
            if self.exists(f"trials/{trial_id}/{CHECKPOINTS}/{timesteps}/state.json"):
                shutil.rmtree(target, ignore_errors=True)
                for info in self.fs.get_file_info(fs.FileSelector(source)):
                    if info.type == fs.FileType.File:
                        self._download(info, source, target)
                return timesteps
        return 0

    def download_trials(self, folder: Path, names: list[str] | None = None) -> list[str]:
        """Download ``trials/<name>/`` (every trial, or those of ``names``; not their checkpoints) and
        ``benchmark.json`` into the log folder ``folder``, replacing what is there; the names downloaded. A path that
        would leave ``folder`` or a file over :data:`MAX_FILE_BYTES` is refused (a ValueError)."""
        from pyarrow import fs

        trials = self._path("trials")
        if names is None:
            listing = self.fs.get_file_info(fs.FileSelector(trials, allow_not_found=True))
            names = [PurePosixPath(info.path).name for info in listing if info.type == fs.FileType.Directory]
        for name in names:
            source = f"{trials}/{name}"
            infos = self.fs.get_file_info(fs.FileSelector(source, recursive=True, allow_not_found=True))
            target = folder / "trials" / name
            shutil.rmtree(target, ignore_errors=True)
            for info in infos:
                if info.type == fs.FileType.File and not info.path.startswith(f"{source}/{CHECKPOINTS}/"):
                    self._download(info, source, target)
        if self.exists("benchmark.json"):
            self._download(self.fs.get_file_info(self._path("benchmark.json")), str(self.root), folder)
        return names

    def _download(self, info: Any, source: str, target: Path) -> None:
        relative = PurePosixPath(info.path).relative_to(source)
        local = target.joinpath(*relative.parts)
        if ".." in relative.parts or not local.resolve().is_relative_to(target.resolve()):
            raise ValueError(f"{self.uri}: {info.path} would be written outside {target}.")
        if info.size > MAX_FILE_BYTES:
            raise ValueError(f"{self.uri}: {info.path} holds {info.size:,} bytes, more than {MAX_FILE_BYTES:,}.")
        local.parent.mkdir(parents=True, exist_ok=True)
        start = time.perf_counter()
        with self.fs.open_input_stream(info.path) as stream, local.open("wb") as out:
            shutil.copyfileobj(stream, out)
        self.sync_s, self.bytes = self.sync_s + time.perf_counter() - start, self.bytes + info.size

    def _copy(self, path: Path, target: str) -> None:
        """Upload the local file ``path`` to ``target`` (a path in the storage's file system)."""
        start = time.perf_counter()
        with path.open("rb") as source, self.fs.open_output_stream(target) as stream:
            shutil.copyfileobj(source, stream)
        self.sync_s, self.bytes = self.sync_s + time.perf_counter() - start, self.bytes + path.stat().st_size


def _uploaded(folder: Path) -> list[Path]:
    """The files of a trial folder its upload takes (no link, no checkpoint file but its step count)."""
    files = []
    for path in folder.rglob("*"):
        relative = path.relative_to(folder).as_posix()
        if path.is_symlink() or not path.is_file() or relative.startswith("."):
            continue
        if relative.startswith("checkpoint/") and relative != CHECKPOINT_KEPT:
            continue
        files.append(path)
    return files


__all__ = ["GridStorage"]
