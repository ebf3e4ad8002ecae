"""Faults a user meets, made for real (issue 76): signals at any moment from the first import, a
full disk (a small tmpfs), a read-only mount (a read-only bind mount) and a folder of another user
(a non-root user). Each ends in one line, the documented exit code and no lost or half-written
file. The mounts are made in a user and mount namespace of the test's own (``unshare``); where the
machine allows none, those tests skip and say so."""

from __future__ import annotations

import os
import resource
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import pytest

from sb3_marl.cli import main

SB3_MARL = str(Path(sys.executable).parent / "sb3-marl")
RUN = "ma2c/sb3_marl-LaneChange-density1-v0_1"
TINY = ["-n", "600", "--eval-freq", "300", "--eval-episodes", "1", "-params", "n_steps:20"]


def _lines(stderr: str) -> list[str]:
    """stderr without the cold cache's compile notice."""
    return [line for line in stderr.splitlines() if not line.startswith("sb3-marl: compiling")]


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    """One tiny MA2C run folder."""
    folder = tmp_path_factory.mktemp("logs")
    assert main(["train", "-f", str(folder), *TINY]) == 0
    return folder


def _namespace_error() -> str | None:
    """Why no tmpfs can be mounted in a namespace of our own here (None: it can)."""
    if shutil.which("unshare") is None:
        return "no `unshare` on this machine"
    probe = subprocess.run(
        ["unshare", "--user", "--map-root-user", "--mount", "sh", "-c", "mount -t tmpfs -o size=64k tmpfs /tmp"],
        capture_output=True,
        text=True,
    )
    return None if probe.returncode == 0 else f"no mount namespace for this user ({probe.stderr.strip()[:200]})"


NAMESPACE_ERROR = _namespace_error()
needs_mounts = pytest.mark.skipif(NAMESPACE_ERROR is not None, reason=f"needs a tmpfs / bind mount: {NAMESPACE_ERROR}")


def in_namespace(mounts: str, argv: list[str], timeout: float = 300) -> subprocess.CompletedProcess[str]:
    """``argv`` run in a user and mount namespace of its own after the shell commands ``mounts``
    (the mounts vanish with it)."""
    script = f"{mounts} && exec {shlex.join(argv)}"
    return subprocess.run(
        ["unshare", "--user", "--map-root-user", "--mount", "sh", "-c", script],
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def tmpfs(folder: Path, size: str) -> str:
    return f"mount -t tmpfs -o size={size} tmpfs {shlex.quote(str(folder))}"


def read_only(source: Path, target: Path) -> str:
    """``source`` seen read-only at ``target``."""
    src, dst = shlex.quote(str(source)), shlex.quote(str(target))
    return f"mount --bind {src} {dst} && mount -o remount,bind,ro {dst}"


def assert_whole_zips(folder: Path) -> None:
    """Every model zip left in ``folder`` reads back whole, and no temporary file of a write is left."""
    for path in folder.rglob("*.zip"):
        with zipfile.ZipFile(path) as archive:
            assert archive.testzip() is None, path
    assert not [path for path in folder.rglob("*") if "partial" in path.name], list(folder.rglob("*partial*"))


@needs_mounts
def test_training_onto_a_disk_that_fills_names_the_last_whole_checkpoint(tmp_path):
    """A 700 kB tmpfs holds the run's files and two of its ~210 kB checkpoints, then fills."""
    disk = tmp_path / "disk"
    disk.mkdir()
    saved = tmp_path / "saved"
    flags = "-n 6000 --save-freq 600 --eval-freq 1200 --eval-episodes 1 -params n_steps:20 --verbose 0"
    argv = [SB3_MARL, "train", "-f", str(disk), *flags.split()]
    # the tmpfs is gone with the namespace: copy what the run left before it ends
    completed = in_namespace(
        tmpfs(disk, "700k"),
        ["sh", "-c", f"{shlex.join(argv)}; code=$?; cp -r {shlex.quote(str(disk))} {shlex.quote(str(saved))}; exit $code"],
    )
    assert completed.returncode == 1, completed.stderr
    lines = _lines(completed.stderr)
    assert "Traceback" not in completed.stderr and len(lines) == 1, completed.stderr
    assert "no space left on the device" in lines[0] and "free some space" in lines[0], lines
    checkpoints = sorted((saved / RUN).glob("rl_model_*_steps.zip"), key=lambda p: int(p.stem.split("_")[2]))
    assert checkpoints and f"{checkpoints[-1].name}" in lines[0], (lines, checkpoints)
    assert_whole_zips(saved)


@needs_mounts
def test_training_onto_a_full_disk_names_the_file_it_could_not_start(tmp_path):
    """A disk already full: SB3's Monitor cannot write its header; the message names that file."""
    disk = tmp_path / "disk"
    disk.mkdir()
    fill = f"(cat /dev/zero > {shlex.quote(str(disk / 'filler'))} 2> /dev/null || true)"
    completed = in_namespace(f"{tmpfs(disk, '64k')} && {fill}", [SB3_MARL, "train", "-f", str(disk / "logs"), *TINY])
    lines = _lines(completed.stderr)
    assert completed.returncode == 1 and "Traceback" not in completed.stderr and len(lines) == 1, completed.stderr
    assert lines[0].startswith(f"sb3-marl train: error: no space left on the device of '{disk / 'logs' / RUN}/monitor.csv'")


@needs_mounts
@pytest.mark.parametrize("command", [["evaluate", "--eval-episodes", "2", "--verbose", "0"], ["plot"]])
def test_evaluate_and_plot_onto_a_full_disk_end_in_one_line(run, tmp_path, command):
    """The run copied onto a tmpfs whose last bytes a file takes: the work is done, its writes fail."""
    disk = tmp_path / "disk"
    disk.mkdir()
    source, filler = shlex.quote(str(run)), shlex.quote(str(disk / "filler"))
    fill = f"cp -r {source}/. {shlex.quote(str(disk))} && (cat /dev/zero > {filler} 2> /dev/null || true)"
    completed = in_namespace(f"{tmpfs(disk, '2m')} && {fill}", [SB3_MARL, *command, "-f", str(disk)])
    assert completed.returncode == 1, completed.stderr
    lines = _lines(completed.stderr)
    assert "Traceback" not in completed.stderr and len(lines) == 1, completed.stderr
    assert lines[0].startswith(f"sb3-marl {command[0]}: error: no space left on the device of '{disk}"), lines


@needs_mounts
@pytest.mark.parametrize(
    "command",
    [["evaluate", "--eval-episodes", "2", "--verbose", "0"], ["plot"], ["train", *TINY, "--verbose", "0"]],
)
def test_a_read_only_mount_is_one_line(run, tmp_path, command):
    """The run folder mounted read-only: each command refuses before any work (exit 2), naming the
    flag of the folder it would write into."""
    view = tmp_path / "view"
    view.mkdir()
    completed = in_namespace(read_only(run, view), [SB3_MARL, *command, "-f", str(view)])
    lines = _lines(completed.stderr)
    assert completed.returncode == 2 and "Traceback" not in completed.stderr and len(lines) == 1, completed.stderr
    flag = "-o/--output" if command[0] == "plot" else "-f/--log-folder"
    assert lines[0].startswith(f"sb3-marl {command[0]}: error: {flag}: ") and "cannot be written" in lines[0], lines


def _as_another_user() -> list[str] | None:
    """The command prefix that runs as a user who owns nothing here (nobody), or None."""
    if os.geteuid() != 0:
        return []
    setpriv = shutil.which("setpriv")
    return None if setpriv is None else [setpriv, "--reuid=65534", "--regid=65534", "--clear-groups"]


@pytest.mark.skipif(_as_another_user() is None, reason="runs as root without setpriv: no other user to be")
def test_folders_of_another_user_are_one_line(run, tmp_path_factory):
    """As a user who may not write (or read) the folders: train -f exits 2 before any folder;
    evaluate of a run it may not read ends in one line."""
    shared = Path(tempfile.mkdtemp(prefix="sb3-marl-faults-"))  # in the temporary folder, which every user may enter
    shared.chmod(0o755)
    try:
        theirs = shared / "theirs"
        theirs.mkdir(mode=0o755)
        private = shared / "private"
        shutil.copytree(run, private)
        private.chmod(0o700)
        if os.geteuid() != 0:  # as the owner, only the mode can say "not yours"
            theirs.chmod(0o555)
        prefix = _as_another_user() or []

        cache = shared / "cache"  # a kernel cache and a home this user may write
        cache.mkdir(mode=0o777)
        cache.chmod(0o777)

        def sb3_marl(*argv: str) -> subprocess.CompletedProcess[str]:
            env = {**os.environ, "HOME": str(cache), "NUMBA_CACHE_DIR": str(cache / "numba"), "MPLCONFIGDIR": str(cache)}
            return subprocess.run([*prefix, SB3_MARL, *argv], capture_output=True, text=True, env=env, timeout=300)

        train = sb3_marl("train", "-f", str(theirs / "logs"), *TINY)
        assert train.returncode == 2, train.stderr
        expected = f"-f/--log-folder: '{theirs / 'logs'}' cannot be written: '{theirs}' is not writable."
        assert _lines(train.stderr) == [f"sb3-marl train: error: {expected}"]
        assert list(theirs.iterdir()) == []
        if os.geteuid() == 0:  # as the owner, the 0700 folder is readable: nothing to show
            readers = [
                ["evaluate", "-f", str(private), "--eval-episodes", "1"],
                ["plot", "-f", str(private)],
                ["summary", "-f", str(private)],  # said "no evaluated run" before
                ["benchmark", "report", "-f", str(private), "-o", str(shared / "report")],
            ]
            mine = shared / "mine"  # the user's own log folder, with another user's TensorBoard folder in it
            (mine / "tensorboard").mkdir(parents=True)
            os.chown(mine, 65534, 65534)
            train = sb3_marl("train", "-f", str(mine), *TINY)
            board = mine / "tensorboard"
            expected = f"-tb/--tensorboard-log: '{board}' cannot be written: '{board}' is not writable."
            assert train.returncode == 2 and _lines(train.stderr) == [f"sb3-marl train: error: {expected}"], train.stderr
            for argv in readers:
                done = sb3_marl(*argv)
                lines = _lines(done.stderr)
                assert done.returncode in (1, 2) and "Traceback" not in done.stderr and len(lines) == 1, (argv, done.stderr)
                assert f"no permission for '{private}" in lines[0], lines
    finally:
        shutil.rmtree(shared)


def _no_large_files() -> None:
    """In the child: files over 64 KB cannot be written (the OS refuses the write, EFBIG), as on
    a full disk; SIGXFSZ ignored so that the write fails instead of killing the process."""
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (64_000, 64_000))


def test_a_write_the_os_refuses_gives_one_message(tmp_path):
    completed = subprocess.run(
        [SB3_MARL, "train", "-f", str(tmp_path / "logs"), "-n", "600", "--eval-freq", "-1", "-params", "n_steps:20"],
        capture_output=True,
        text=True,
        preexec_fn=_no_large_files,
        timeout=300,
    )
    assert completed.returncode == 1, completed.stderr
    assert "Traceback" not in completed.stderr
    assert "could not write" in completed.stderr and "free some space" in completed.stderr, completed.stderr


def test_evaluate_whose_writes_the_os_refuses_ends_in_one_line(run, tmp_path):
    """A full disk (here: a file-size limit) after the evaluation's work: exit 1, one line naming
    the folder and what to do, no traceback, no temporary file left."""
    argv = [SB3_MARL, "evaluate", "-f", str(run), "--eval-episodes", "2", "--verbose", "0"]
    completed = subprocess.run(argv, capture_output=True, text=True, preexec_fn=_no_large_files, timeout=300)
    assert completed.returncode == 1, completed.stderr
    lines = [line for line in completed.stderr.splitlines() if not line.startswith("sb3-marl: compiling")]
    assert len(lines) == 1 and lines[0].startswith("sb3-marl evaluate: error: a file in "), completed.stderr
    assert "free some space" in lines[0] and ".partial" not in lines[0]
    assert not list(run.rglob(".*partial*"))


@pytest.mark.parametrize("command", [["evaluate", "--eval-episodes", "3000"], ["baselines", "--eval-episodes", "3000"]])
def test_ctrl_c_is_one_line_and_exit_130(run, tmp_path, command):
    """Ctrl-C during a long evaluation: exit 130 with one line on stderr, no traceback, no file."""
    extra = ["-f", str(run), "-o", str(tmp_path / "out.json")] if command[0] == "evaluate" else ["-o", str(tmp_path / "b.md")]
    process = subprocess.Popen([SB3_MARL, *command, *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(8)
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_sigterm_of_a_long_command_is_one_line_and_exit_143(tmp_path):
    argv = [SB3_MARL, "baselines", "--eval-episodes", "3000", "-o", str(tmp_path / "b.md")]
    process = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(8)
    process.send_signal(signal.SIGTERM)
    _, err = process.communicate(timeout=60)
    assert process.returncode == 143, err
    lines = [line for line in err.splitlines() if not line.startswith("sb3-marl: compiling")]
    assert lines == [
        "sb3-marl baselines: interrupted (SIGTERM); files it had written are complete (each is written whole), "
        "nothing else was written."
    ]
    assert list(tmp_path.iterdir()) == []


def _catches_sigterm(pid: int) -> bool:
    """Whether process ``pid`` has a handler of its own for SIGTERM (Linux's /proc SigCgt mask)."""
    status = Path(f"/proc/{pid}/status").read_text()
    caught = int(next(line.split()[1] for line in status.splitlines() if line.startswith("SigCgt:")), 16)
    return bool(caught >> (signal.SIGTERM - 1) & 1)


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="reads the signal mask from Linux's /proc")
@pytest.mark.parametrize(("signum", "code"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_while_the_package_imports_is_one_line(tmp_path, signum, code):
    # the console script's launcher takes both signals before `import sb3_marl` (~2 s): the signal
    # is sent as soon as it has, while the import runs
    argv = [SB3_MARL, "train", "--algo", "ma2c", "-n", "300", "-f", str(tmp_path / "logs")]
    process = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 10
    while not _catches_sigterm(process.pid) and time.monotonic() < deadline:
        time.sleep(0.005)
    process.send_signal(signum)
    _, err = process.communicate(timeout=60)
    assert process.returncode == code, err
    assert err.splitlines() == [f"sb3-marl: interrupted ({signal.Signals(signum).name}) while starting; nothing was written."]
    assert list(tmp_path.iterdir()) == []
