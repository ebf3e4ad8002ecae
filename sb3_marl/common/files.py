"""The project's files: written so that a crash or an interrupt never leaves a half-written one,
and read as data (JSON objects, replay-buffer arrays, run-folder YAML: never unpickled, never run)."""

from __future__ import annotations

import json
import os
import re
import socket
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import yaml

#: This machine's name in temporary files' names (no dots or separators).
HOST = re.sub(r"[^A-Za-z0-9_-]", "_", socket.gethostname())
#: A temporary file of :func:`replaced_atomically`: its host (absent in older names) and process id.
PARTIAL = re.compile(r"^\..+\.(?:(?P<host>[A-Za-z0-9_-]+)-)?(?P<pid>\d+)\.partial(\.[^.]+)?$")


@contextmanager
def replaced_atomically(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (``.<stem>.<host>-<pid>.partial<suffix>``) to write to.

    The host and process id in the name keep two processes that write the same file (two benchmark
    launchers on one folder) from renaming each other's temporary file away.

    When the block ends normally, the temporary file replaces ``path`` in one rename. When it
    raises (an error, Ctrl-C, SIGTERM turned into KeyboardInterrupt), the temporary file is
    removed and ``path`` keeps its previous content. A process killed mid-write cannot remove its
    own: the next write into the folder removes every temporary file of a process of this host
    that is gone (:func:`remove_debris`).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    remove_debris(path.parent)
    temporary = path.with_name(f".{path.stem}.{HOST}-{os.getpid()}.partial{path.suffix}")
    try:
        yield temporary
        os.replace(temporary, path)
    except BaseException as error:
        temporary.unlink(missing_ok=True)
        if isinstance(error, OSError) and error.filename is None:  # a failed write or close names no file
            error.filename = str(temporary)
        raise


def _running(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        return True
    return True


def remove_debris(folder: str | Path) -> list[Path]:
    """Remove the temporary files that processes of this host which are gone left in ``folder``
    (killed mid-write); returns them. Another host's are left alone (its process may be alive)."""
    removed = []
    for candidate in Path(folder).glob(".*.partial*"):
        match = PARTIAL.match(candidate.name)
        if match is None or (match["host"] or HOST) != HOST or _running(int(match["pid"])):
            continue
        candidate.unlink(missing_ok=True)
        removed.append(candidate)
    return removed


def inside(path: str | Path, folder: str | Path) -> Path:
    """``path`` if it lies in ``folder`` once links are followed; a ValueError naming it if a link
    leads out of the folder (a run's or a grid's files are read from the folder, never through a
    link to elsewhere)."""
    resolved, root = Path(path).resolve(), Path(folder).resolve()
    if not resolved.is_relative_to(root):
        raise ValueError(f"{path} is a link to {resolved}, outside {folder}; it is not followed.")
    return Path(path)


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically (:func:`replaced_atomically`); returns the path."""
    with replaced_atomically(path) as temporary:
        temporary.write_text(text, encoding="utf-8")
    return Path(path)


def save_figure(figure: Any, path: str | Path, dpi: int = 100) -> Path:
    """``figure.savefig`` to ``path`` atomically (the format from the suffix); returns the path."""
    with replaced_atomically(path) as temporary:
        figure.savefig(temporary, dpi=dpi)
    return Path(path)


#: The largest JSON file the project reads [bytes] (a held-out evaluation's is about 1 MB).
MAX_JSON_BYTES = 50_000_000


def read_json_object(path: str | Path) -> dict[str, Any]:
    """The JSON object (a mapping) in ``path``; a ValueError naming the file and what is wrong
    (unreadable, truncated, not JSON, or JSON that is not an object)."""
    try:
        size = Path(path).stat().st_size
        if size > MAX_JSON_BYTES:
            raise ValueError(f"{size:,} bytes, more than the {MAX_JSON_BYTES:,} a JSON file here may have")
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, ValueError) as error:
        raise ValueError(f"{path} is not readable JSON ({type(error).__name__}: {error}).") from None
    return json_object(text, path)


def json_object(text: str | bytes, name: str | Path) -> dict[str, Any]:
    """The JSON object (a mapping) in ``text`` (bytes: UTF-8), read from ``name``; a ValueError
    naming it and what is wrong (not UTF-8, not JSON, or JSON that is not an object)."""
    try:
        data = json.loads(text)
    except (ValueError, RecursionError) as error:
        raise ValueError(f"{name} is not readable JSON ({type(error).__name__}: {error}).") from None
    if not isinstance(data, dict):
        raise ValueError(f"{name} holds a JSON {type(data).__name__}, expected an object.")
    return data


#: The largest array an ``evaluations.npz`` may hold [bytes] (a full-budget run's are kilobytes).
MAX_EVALUATION_BYTES = 100_000_000


def npz_headers(path: str | Path) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
    """Each array of an npz as (shape, dtype), read from the headers of its members without
    reading their data; a ValueError naming the file if it is not an npz of plain arrays."""
    headers = {}
    try:
        with zipfile.ZipFile(path) as archive:
            for member in archive.infolist():
                if not member.filename.endswith(".npy"):
                    raise ValueError(f"member {member.filename!r} is not an array")
                with archive.open(member) as file:
                    version = np.lib.format.read_magic(file)
                    read_header = (
                        np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
                    )
                    shape, _, dtype = read_header(file)
                if dtype.hasobject:
                    raise ValueError(f"array {member.filename[:-4]!r} holds Python objects")
                headers[member.filename[:-4]] = (tuple(shape), dtype)
    except Exception as error:  # zipfile alone raises BadZipFile, NotImplementedError, RuntimeError, EOFError, ...
        raise ValueError(f"{path} is not a readable npz of arrays ({type(error).__name__}: {error}).") from None
    return headers


def _array_bytes(shape: tuple[int, ...], dtype: np.dtype) -> int:
    return int(np.prod(shape, dtype=np.float64) * dtype.itemsize)


def read_evaluations(path: str | Path) -> dict[str, Any]:
    """The arrays of an ``evaluations.npz``; a ValueError naming the file if it is unreadable
    (truncated, not an npz, pickled objects: never unpickled) or an array's header claims more
    than :data:`MAX_EVALUATION_BYTES` (checked before any array is read)."""
    for key, (shape, dtype) in npz_headers(path).items():
        if _array_bytes(shape, dtype) > MAX_EVALUATION_BYTES:
            raise ValueError(f"{path}: array {key!r} of shape {shape} ({dtype}) is larger than an evaluations.npz holds.")
    try:
        with np.load(path, allow_pickle=False) as log:
            return {key: log[key] for key in log.files}
    except Exception as error:  # zipfile.BadZipFile, OSError, ValueError, EOFError alike
        raise ValueError(f"{path} is not a readable evaluations.npz ({type(error).__name__}: {error}).") from None


#: The replay buffer of a checkpoint, as arrays (never a pickle).
REPLAY_BUFFER_FILE = "replay_buffer.npz"


def write_replay_buffer(buffer: Any, path: str | Path) -> None:
    """An SB3 replay buffer's arrays (every ndarray attribute) and its ``pos`` / ``full`` as an
    npz, written atomically: data that :func:`read_replay_buffer` reads back without unpickling."""
    arrays: dict[str, Any] = {key: value for key, value in vars(buffer).items() if isinstance(value, np.ndarray)}
    arrays.update(pos=np.array(buffer.pos, dtype=np.int64), full=np.array(buffer.full, dtype=bool))
    with replaced_atomically(path) as temporary, open(temporary, "wb") as file:
        np.savez(file, **arrays)


def read_replay_buffer(buffer: Any, path: str | Path) -> None:
    """Fill ``buffer`` (a freshly built SB3 replay buffer of the same sizes) from
    :func:`write_replay_buffer`'s npz, as data: a ValueError naming the file and the array when an
    array is missing, unknown or of another shape or dtype (nothing is changed then), or when the
    file is unreadable or holds pickled objects."""
    expected = {key: value for key, value in vars(buffer).items() if isinstance(value, np.ndarray)}
    headers = npz_headers(path)  # shapes and dtypes checked before any array is read
    for key in sorted({*expected, *headers} - {"pos", "full"}):
        have, want = headers.get(key), expected.get(key)
        if have is None or want is None or have != (want.shape, want.dtype):
            found = "missing" if have is None else f"{have[1]} {have[0]}"
            wanted = "no such array" if want is None else f"{want.dtype} {want.shape}"
            raise ValueError(f"{path}: array {key!r} is {found}, the model's replay buffer expects {wanted}.")
    for key in ("pos", "full"):
        if key in headers and headers[key][0] != ():
            raise ValueError(f"{path}: {key!r} must be a scalar, got shape {headers[key][0]}.")
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {key: data[key] for key in data.files}
    except Exception as error:
        raise ValueError(f"{path} is not a readable replay buffer ({type(error).__name__}: {error}).") from None
    pos, full = arrays.get("pos"), arrays.get("full")
    if pos is None or full is None or pos.shape != () or full.shape != () or not 0 <= int(pos) < buffer.buffer_size:
        raise ValueError(f"{path}: 'pos' and 'full' must be scalars with 0 <= pos < {buffer.buffer_size}.")
    for key in expected:
        setattr(buffer, key, arrays[key])
    buffer.pos, buffer.full = int(pos), bool(full)


#: Bounds of a YAML file the project reads: its size [bytes], and its nodes with every alias
#: expanded (a "billion laughs" file of a few hundred bytes expands to billions through aliases).
MAX_YAML_BYTES, MAX_YAML_NODES = 1_000_000, 100_000


class RunFileLoader(yaml.SafeLoader):
    """yaml's SafeLoader plus rl-zoo's ``!!python/object/apply:collections.OrderedDict`` (a list of
    [key, value] pairs, read as a dict); every other Python tag is refused, and so is a document of
    more than :data:`MAX_YAML_NODES` nodes once its aliases are expanded (counted, not expanded)."""

    def get_single_node(self) -> Any:
        node = super().get_single_node()
        if node is not None and _expanded_size(node, {}) > MAX_YAML_NODES:
            raise yaml.YAMLError(f"more than {MAX_YAML_NODES:,} values once its aliases are expanded")
        return node


def _expanded_size(node: yaml.Node, sizes: dict[int, int]) -> int:
    """Nodes under ``node`` with aliases expanded (an alias is the node it names: shared, so each
    node's size is computed once)."""
    if id(node) not in sizes:
        sizes[id(node)] = 1  # a node that contains itself counts once
        children: list[Any] = []
        if isinstance(node, yaml.MappingNode):
            children = [child for pair in node.value for child in pair]
        elif isinstance(node, yaml.SequenceNode):
            children = node.value
        sizes[id(node)] = 1 + sum(_expanded_size(child, sizes) for child in children)
    return sizes[id(node)]


def load_yaml(path: str | Path) -> Any:
    """The plain data of a YAML file (:class:`RunFileLoader`), at most :data:`MAX_YAML_BYTES` long.

    :raises ValueError: naming the file if it is larger
    :raises yaml.YAMLError: if it is not plain-data YAML within :data:`MAX_YAML_NODES` (or nests
        beyond Python's recursion limit)
    """
    size = Path(path).stat().st_size
    if size > MAX_YAML_BYTES:
        raise ValueError(f"{path} is {size:,} bytes, more than the {MAX_YAML_BYTES:,} a YAML file here may have.")
    try:
        return yaml.load(Path(path).read_text(), Loader=RunFileLoader)
    except RecursionError:
        raise yaml.YAMLError("nested too deeply") from None


def _ordered_dict(loader: yaml.SafeLoader, node: yaml.Node) -> dict:
    (pairs,) = loader.construct_sequence(node, deep=True)
    return dict(pairs)


RunFileLoader.add_constructor("tag:yaml.org,2002:python/object/apply:collections.OrderedDict", _ordered_dict)
RunFileLoader.add_constructor(
    "tag:yaml.org,2002:python/tuple", lambda loader, node: tuple(loader.construct_sequence(node, deep=True))
)


def read_run_yaml(path: str | Path) -> dict[str, Any]:
    """A run folder's ``config.yml`` / ``args.yml`` as a dict; a ValueError naming the file for
    YAML that is not plain data (e.g. a ``!!python/object/apply:os.system`` tag) or not a mapping."""
    try:
        data = load_yaml(path)
    except yaml.YAMLError as error:
        raise ValueError(
            f"{path} is not a plain-data YAML file of a run ({str(error).splitlines()[0]}); "
            "it is not read (it could run code)."
        ) from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ValueError(f"{path} must be a mapping of keys to values, got a {type(data).__name__}.")
    return data
