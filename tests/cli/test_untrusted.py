"""Files and strings a stranger could hand a user never run code, and every bad input gets one
clear message (issue: loading what others share). Each payload below is real: it writes a marker
file when unpickled or evaluated, as the tests with ``trust_remote_code`` show."""

import base64
import contextlib
import io
import json
import os
import re
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import cloudpickle
import numpy as np
import pytest

from sb3_marl.algos import get_algo
from sb3_marl.algos.common.loading import UnsafeModelError
from sb3_marl.cli import main
from sb3_marl.common.files import read_run_yaml
from sb3_marl.common.literals import parse_literal

ENV = "sb3_marl/LaneChange-density1-v0"
ENV_NAME = "sb3_marl-LaneChange-density1-v0"
TINY = ["-n", "600", "--eval-freq", "300", "--eval-episodes", "1", "-params", "n_steps:20"]
SB3_MARL = str(Path(sys.executable).parent / "sb3-marl")


class Payload:
    """Unpickling this object creates ``marker`` (what a malicious zip would do instead)."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    """One tiny MA2C run folder."""
    folder = tmp_path_factory.mktemp("logs")
    assert main(["train", "-f", str(folder), *TINY]) == 0
    return folder


def poisoned_copy(run: Path, tmp_path: Path, entry: str = "policy_class") -> tuple[Path, Path]:
    """A copy of the run whose model zip carries a payload (logs, marker): its data's ``entry``
    cloudpickled, or for a member name (``policy.pth``, ...) that member a ``torch.save`` of a
    state dict whose value is the payload (added if the zip had no such member)."""
    import torch

    logs = tmp_path / "logs"
    subprocess.run(["cp", "-r", str(run), str(logs)], check=True)
    marker = tmp_path / "marker"
    model = logs / "ma2c" / f"{ENV_NAME}_1" / f"{ENV_NAME}.zip"
    with zipfile.ZipFile(model) as archive:
        files = {name: archive.read(name) for name in archive.namelist()}
    if entry.endswith(".pth"):
        weights = io.BytesIO()
        torch.save({"weight": Payload(marker)}, weights)
        files[entry] = weights.getvalue()
    else:
        data = json.loads(files["data"])
        data[entry] = {
            ":type:": "<class 'abc.ABCMeta'>",
            ":serialized:": base64.b64encode(cloudpickle.dumps(Payload(marker))).decode(),
        }
        files["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(model, "w") as archive:
        for name, content in files.items():
            archive.writestr(name, content)
    return logs, marker


@pytest.mark.parametrize("entry", ["policy_class", "observation_space", "lr_schedule"])
def test_a_poisoned_model_zip_is_refused_by_every_command(run, tmp_path, capsys, entry):
    logs, marker = poisoned_copy(run, tmp_path, entry)
    model = logs / "ma2c" / f"{ENV_NAME}_1" / f"{ENV_NAME}.zip"
    for argv in (
        ["evaluate", "-f", str(logs), "--eval-episodes", "1"],
        ["record-video", "-f", str(logs), "-o", str(tmp_path / "v.mp4")],
        ["train", "-f", str(tmp_path / "resumed"), "-i", str(model), *TINY],
    ):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert f"'{entry}'" in err and "trust_remote_code" in err, err
        assert not marker.exists()
    assert not (tmp_path / "resumed").exists()
    with pytest.raises(UnsafeModelError, match=entry):
        get_algo("ma2c").load(model)
    assert not marker.exists()
    # the payload is real: trusting the file runs it (with a warning naming the file)
    # the payload is no policy class (the load then fails): what matters is that it ran
    with pytest.warns(UserWarning, match="trust_remote_code=True"), contextlib.suppress(Exception):
        get_algo("ma2c").load(model, trust_remote_code=True)
    assert marker.exists()


@pytest.mark.parametrize("member", ["policy.pth", "pytorch_variables.pth", "policy.optimizer.pth"])
def test_a_model_zip_with_pickled_weights_is_refused_in_one_line(run, tmp_path, capsys, member):
    """A zip whose ``member`` holds a pickled payload where tensors belong: every command exits 2
    with one line naming the zip and the member (not torch's paragraph on ``weights_only``), and
    ``load`` raises UnsafeModelError, with or without trust_remote_code; the payload never runs."""
    import torch

    logs, marker = poisoned_copy(run, tmp_path, member)
    model = logs / "ma2c" / f"{ENV_NAME}_1" / f"{ENV_NAME}.zip"
    refusal = f"{model}: {member}: not plain tensors (a pickled object where weights belong"
    completed = subprocess.run(
        [SB3_MARL, "evaluate", "-f", str(logs), "--eval-episodes", "1"], capture_output=True, text=True, timeout=300
    )
    assert completed.returncode == 2, completed.stderr
    (line,) = completed.stderr.splitlines()
    assert line.startswith(f"sb3-marl evaluate: error: {refusal}") and line.endswith("refused without running it."), line
    for argv in (
        ["record-video", "-f", str(logs), "-o", str(tmp_path / "v.mp4")],
        ["train", "-f", str(tmp_path / "resumed"), "-i", str(model), *TINY],
    ):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and refusal in err, err
    assert not (tmp_path / "resumed").exists() and not (tmp_path / "v.mp4").exists()
    with pytest.raises(UnsafeModelError, match=re.escape(f"{member}: not plain tensors")):
        get_algo("ma2c").load(model)
    with pytest.warns(UserWarning, match="trust_remote_code=True"), pytest.raises(UnsafeModelError, match=member):
        get_algo("ma2c").load(model, trust_remote_code=True)
    assert not marker.exists()
    # the payload is real: unpickling the member runs it
    with zipfile.ZipFile(model) as archive:
        torch.load(io.BytesIO(archive.read(member)), weights_only=False)
    assert marker.exists()


def test_clean_models_load_without_unpickling_anything(run, monkeypatch):
    """Every committed learner's zip loads with cloudpickle disabled."""

    def refuse(*args, **kwargs):
        raise AssertionError("cloudpickle.loads called")

    monkeypatch.setattr(cloudpickle, "loads", refuse)
    monkeypatch.setattr("pickle.loads", refuse)
    model = get_algo("ma2c").load(run / "ma2c" / f"{ENV_NAME}_1" / f"{ENV_NAME}.zip")
    assert model.num_timesteps >= 600 and model.lr_schedule(1.0) > 0
    grid = Path(__file__).resolve().parents[2] / "results" / "paper-grid" / "trials"
    for algo in ("ma2c", "mappo", "madqn", "maacktr"):
        (zip_path,) = (grid / f"{algo}_density1_default_seed0" / algo).glob("*_1/*.zip")
        assert get_algo(algo).load(zip_path, device="cpu").num_timesteps > 0


@pytest.mark.parametrize("name", ["config.yml", "args.yml"])
def test_run_yaml_with_a_python_tag_is_refused(run, tmp_path, capsys, name):
    logs = tmp_path / "logs"
    subprocess.run(["cp", "-r", str(run), str(logs)], check=True)
    marker = tmp_path / "marker"
    path = logs / "ma2c" / f"{ENV_NAME}_1" / ENV_NAME / name
    path.write_text(f"!!python/object/apply:os.system ['touch {marker}']\n")
    command = ["evaluate", "-f", str(logs), "--eval-episodes", "1"] if name == "config.yml" else ["summary", "-f", str(logs)]
    if name == "args.yml":
        assert main(["evaluate", "-f", str(logs), "--eval-episodes", "1"]) == 0  # an evaluation to summarise
    assert main(command) == 2
    assert name in capsys.readouterr().err and not marker.exists()
    with pytest.raises(ValueError, match="plain-data YAML"):
        read_run_yaml(path)


def test_plot_names_a_run_yaml_with_a_python_tag(run, tmp_path, capsys):
    logs = tmp_path / "logs"
    subprocess.run(["cp", "-r", str(run), str(logs)], check=True)
    args = logs / "ma2c" / f"{ENV_NAME}_1" / ENV_NAME / "args.yml"
    args.write_text(args.read_text() + f'- !!python/object/apply:os.system ["touch {tmp_path / "marker"}"]\n')
    assert main(["plot", "-f", str(logs), "-o", str(tmp_path / "plots")]) == 2
    assert f"{args} is not a plain-data YAML file" in capsys.readouterr().err
    assert not (tmp_path / "marker").exists() and not (tmp_path / "plots").exists()


LAUGHS = "".join(
    f"{name}: &{name} [{', '.join([f'*{prev}'] * 9) if prev else ', '.join(['lol'] * 9)}]\n"
    for prev, name in zip(["", *"abcdefgh"], "abcdefghi")
)


@pytest.mark.parametrize(
    "text, message",
    [
        (LAUGHS, "more than 100,000 values once its aliases are expanded"),  # ~700 bytes, 9^9 values
        ("a: " + "[" * 5000 + "]" * 5000 + "\n", "nested too deeply"),
        ("a: " + "x" * 1_100_000 + "\n", "bytes, more than the 1,000,000 a YAML file here may have"),
    ],
)
def test_a_small_yaml_cannot_take_the_memory_or_the_stack(tmp_path, capsys, text, message):
    """A hyperparameter file (-c) that expands through aliases (billion laughs), nests past the
    stack, or is over 1 MB: one message, before any folder, in well under a second of work."""

    config = tmp_path / "hyperparams.yml"
    config.write_text(text)
    start = time.perf_counter()
    assert main(["train", "-c", str(config), "-n", "100", "-f", str(tmp_path / "logs")]) == 2
    assert time.perf_counter() - start < 5
    err = capsys.readouterr().err
    assert message in err and str(config) in err and "Traceback" not in err
    assert not (tmp_path / "logs").exists()


def test_a_model_with_non_finite_weights_is_refused_and_loss_weights_are_bounded(run, tmp_path, capsys):
    """A zip whose weights hold NaN (a diverged run): `evaluate` says so in one line instead of a
    torch traceback; loss weights that would overflow to NaN are refused before any folder."""
    import torch

    logs = tmp_path / "logs"
    subprocess.run(["cp", "-r", str(run), str(logs)], check=True)
    zip_path = logs / "ma2c" / f"{ENV_NAME}_1" / f"{ENV_NAME}.zip"
    model = get_algo("ma2c").load(zip_path)
    with torch.no_grad():
        next(model.policy.parameters()).fill_(float("nan"))
    model.save(zip_path)
    assert main(["evaluate", "-f", str(logs), "--eval-episodes", "1"]) == 2
    err = capsys.readouterr().err
    assert f"{zip_path}: the model's weights" in err and "not finite" in err and "Traceback" not in err
    for key in ("prior_coef", "safety_loss_coef"):
        argv = ["train", "-n", "100", "-f", str(tmp_path / key), "-params", f"{key}:1e300", "prior:'idm-mobil'"]
        assert main(argv) == 2
        assert f"Invalid {key}=1e+300" in capsys.readouterr().err and not (tmp_path / key).exists()


def _rewrite_zip(source: Path, target: Path, data: dict) -> None:
    """``source``'s model zip with its ``data`` JSON replaced (the other members as they are)."""
    import zipfile

    with zipfile.ZipFile(source) as old, zipfile.ZipFile(target, "w", zipfile.ZIP_DEFLATED) as new:
        for member in old.infolist():
            new.writestr(member.filename, json.dumps(data) if member.filename == "data" else old.read(member))


def test_small_files_that_claim_large_sizes_are_refused_before_allocating(run, tmp_path):
    """A model zip whose policy_kwargs name 16,000-unit layers, or whose data member inflates past
    10 MB (a 100 kB file), an evaluations.npz whose header claims 4 GB, a replay_buffer.npz whose
    header disagrees with the model's buffer: each refused by its header, naming the file."""
    import io
    import zipfile

    from sb3_marl.algos.common.loading import read_model_data
    from sb3_marl.common.files import read_evaluations, read_replay_buffer

    source = run / "ma2c" / f"{ENV_NAME}_1" / f"{ENV_NAME}.zip"
    data = read_model_data(source)
    wide = tmp_path / "wide.zip"
    _rewrite_zip(source, wide, {**data, "policy_kwargs": {**data["policy_kwargs"], "net_arch": [16000, 16000]}})
    with pytest.raises(ValueError, match=r"wide.zip: policy_kwargs names layers of up to 16,000 units"):
        get_algo("ma2c").load(wide)
    bomb = tmp_path / "bomb.zip"
    _rewrite_zip(source, bomb, {**data, "padding": " " * 11_000_000})
    assert bomb.stat().st_size < 1_000_000
    with pytest.raises(ValueError, match=r"bomb.zip is not a readable SB3 model file .*'data' inflates to 11,0"):
        get_algo("ma2c").load(bomb)

    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False, "shape": (500_000_000,)})
    claims = tmp_path / "evaluations.npz"
    with zipfile.ZipFile(claims, "w") as archive:
        archive.writestr("results.npy", header.getvalue() + bytes(64))
    with pytest.raises(ValueError, match=r"array 'results' of shape \(500000000,\) \(float64\) is larger"):
        read_evaluations(claims)
    madqn = get_algo("madqn")("MlpPolicy", "CartPole-v1", buffer_size=100, learning_starts=0)
    with zipfile.ZipFile(tmp_path / "replay_buffer.npz", "w") as archive:
        archive.writestr("observations.npy", header.getvalue() + bytes(64))
    with pytest.raises(ValueError, match=r"array 'actions' is missing|array 'observations' is float64 \(500000000,\)"):
        read_replay_buffer(madqn.replay_buffer, tmp_path / "replay_buffer.npz")


def test_training_that_diverges_stops_with_a_message_and_saves_nothing_from_it(tmp_path, capsys):
    """An update that makes the weights NaN (learning rate 1e6) stops training within 1,000 AV-steps
    with one message and exit 1; no model with NaN weights is written."""
    argv = ["train", "-n", "2000", "-f", str(tmp_path), "-params", "learning_rate:1e6", "n_steps:20", "--verbose", "0"]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert "training diverged at " in err and "are NaN or infinite" in err and "Traceback" not in err
    assert not list(tmp_path.rglob("*.zip"))


@pytest.mark.parametrize("edit", [{"supervisor_off": 5}, [1, 2]])
def test_summary_and_plot_name_what_they_cannot_use(run, tmp_path, capsys, edit):
    """An evaluation.json edited to a wrong type (`summary`), and `plot -o` naming a file: one
    message each, naming the file or the flag."""
    logs = tmp_path / "logs"
    subprocess.run(["cp", "-r", str(run), str(logs)], check=True)
    assert main(["evaluate", "-f", str(logs), "--eval-episodes", "1"]) == 0
    (evaluation,) = logs.glob("ma2c/*_1/evaluation.json")
    original = json.loads(evaluation.read_text())
    evaluation.write_text(json.dumps({**original, **edit} if isinstance(edit, dict) else edit))
    capsys.readouterr()
    assert main(["summary", "-f", str(logs)]) == 2
    err = capsys.readouterr().err
    assert str(evaluation) in err and "Traceback" not in err
    (tmp_path / "a_file").write_text("mine")
    assert main(["plot", "-f", str(logs), "-o", str(tmp_path / "a_file")]) == 2
    assert "-o/--output" in capsys.readouterr().err and (tmp_path / "a_file").read_text() == "mine"


def test_rl_zoo_run_yaml_still_reads(run):
    config = read_run_yaml(run / "ma2c" / f"{ENV_NAME}_1" / ENV_NAME / "config.yml")
    assert config["env_config"] == {"safety_supervisor": True} and config["n_steps"] == 20


@pytest.mark.parametrize(
    "text",
    [
        "__import__('os').system('touch MARKER')",
        "open('MARKER', 'w')",
        "dict(a=__import__('os'))",
        "[x for x in ()]",
        "1 + 1",
        "nn.Module.__subclasses__()",
    ],
)
def test_hyperparameter_strings_are_never_evaluated(text, tmp_path, capsys):
    text = text.replace("MARKER", str(tmp_path / "marker"))
    with pytest.raises(ValueError, match="Invalid value for policy_kwargs"):
        parse_literal(text, "policy_kwargs")
    with pytest.raises(SystemExit) as exit_info:
        main(["train", "-f", str(tmp_path / "logs"), "-params", f"policy_kwargs:{text}"])
    assert exit_info.value.code == 2 and "policy_kwargs" in capsys.readouterr().err
    conf = tmp_path / "conf.yml"
    conf.write_text(f'{ENV}:\n  policy: MlpPolicy\n  policy_kwargs: "{text}"\n')
    assert main(["train", "-f", str(tmp_path / "logs"), "-c", str(conf), "-n", "100"]) == 2
    assert "policy_kwargs" in capsys.readouterr().err
    assert not (tmp_path / "marker").exists() and not (tmp_path / "logs").exists()


def test_literals_parse():
    from torch import nn

    assert parse_literal("dict(net_arch=[64, 64], activation_fn=nn.Tanh)", "k") == {
        "net_arch": [64, 64],
        "activation_fn": nn.Tanh,
    }
    assert parse_literal("{'comfort': False, 'hdv_politeness': -1.5}", "k") == {"comfort": False, "hdv_politeness": -1.5}
    assert parse_literal("lin_5e-4", "k") == "lin_5e-4" and parse_literal("global", "k") == "global"
    assert parse_literal("local", "k") == "local" and parse_literal("3e-4", "k") == 3e-4
    assert parse_literal("idm-mobil", "prior") == "idm-mobil"  # a hyphenated word, not a subtraction
    with pytest.raises(ValueError, match=r"keys are quoted strings, as in Python: \{'comfort': False\}"):
        parse_literal("{comfort: False}", "env_config")  # a YAML habit


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ("env_config:0", "Invalid env_config=0: expected a mapping"),
        ("env_config:None", "Invalid env_config=None: expected a mapping"),
        ('env_config:""', "Invalid env_config='': expected a mapping"),
        ("policy_kwargs:dict(net_arch=[-1])", "Invalid policy_kwargs={'net_arch': [-1]}"),
        ("policy_kwargs:dict(bogus=1)", "unexpected keyword argument 'bogus'"),
        ("policy_kwargs:5", "Invalid policy_kwargs=5: expected a mapping"),
    ],
)
def test_bad_overrides_exit_2_before_any_folder(params, message, tmp_path, capsys):
    assert main(["train", "-f", str(tmp_path / "logs"), "-n", "100", "-params", params]) == 2
    assert message in capsys.readouterr().err and not (tmp_path / "logs").exists()


@pytest.mark.parametrize("seed", ["-1", "1099511627776"])
def test_bad_seeds_exit_2_before_any_folder(seed, tmp_path, capsys):
    assert main(["train", "-f", str(tmp_path / "logs"), "-n", "100", "--seed", seed]) == 2
    assert "--seed" in capsys.readouterr().err and not (tmp_path / "logs").exists()


def test_unwritable_and_overlong_log_folders_exit_2(tmp_path, capsys, monkeypatch):
    """A log folder inside a read-only folder (mode 0500), an over-long name, /proc, a non-UTF-8
    name: exit 2 naming the flag, nothing made. Root writes into a 0500 folder regardless of its
    mode, so as root the OS's answer for another user (``os.access``: not writable) stands in."""
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    if os.geteuid() == 0:
        access = os.access
        monkeypatch.setattr(
            os,
            "access",
            lambda path, mode, **kw: False if Path(path) == locked and mode & os.W_OK else access(path, mode, **kw),
        )
    try:
        assert not os.access(locked, os.W_OK)
        assert main(["train", "-f", str(locked / "logs"), "-n", "100"]) == 2
        assert f"'{locked}' is not writable" in capsys.readouterr().err
        assert list(locked.iterdir()) == []
    finally:
        locked.chmod(0o700)
        monkeypatch.undo()
    assert main(["train", "-f", str(tmp_path / ("x" * 300)), "-n", "100"]) == 2
    assert "too long" in capsys.readouterr().err
    assert main(["train", "-f", "/proc/nope", "-n", "100"]) == 2  # a folder no one can make
    assert "-f/--log-folder: '/proc/nope' cannot be written: no folder can be made in '/proc'" in capsys.readouterr().err
    assert main(["train", "-f", os.fsdecode(bytes(tmp_path) + b"/\xff\xfe"), "-n", "100"]) == 2
    assert "is not a valid UTF-8 path" in capsys.readouterr().err and list(tmp_path.iterdir()) == [locked]


def test_one_unreadable_trial_is_named_and_the_rest_listed(tmp_path, capsys):
    grid = Path(__file__).resolve().parents[2] / "results" / "paper-grid"
    copy = tmp_path / "grid"
    (copy / "trials").mkdir(parents=True)
    (copy / "benchmark.json").write_text((grid / "benchmark.json").read_text())
    for trial in ("ma2c_density1_default_seed0", "ma2c_density1_default_seed1"):
        subprocess.run(["cp", "-r", str(grid / "trials" / trial), str(copy / "trials" / trial)], check=True)
    broken = copy / "trials" / "ma2c_density1_default_seed1" / "result.json"
    broken.write_text(broken.read_text()[:100])
    assert main(["benchmark", "status", "--grid", "reward", "--seeds", "2", "--densities", "1", "-f", str(copy)]) == 1
    captured = capsys.readouterr()
    assert re.search(r"ma2c_density1_default_seed0 +finished", captured.out) and str(broken) in captured.err
    assert re.search(r"ma2c_density1_default_seed1 +unreadable", captured.out)
    npz = next((copy / "trials" / "ma2c_density1_default_seed0").glob("ma2c/*_1/evaluations.npz"))
    npz.write_bytes(npz.read_bytes()[:200])
    from sb3_marl.benchmark.statistics import load_trials

    problems: list[str] = []
    assert load_trials(copy, problems) == [] and any(str(npz) in p for p in problems)
    plots = tmp_path / "plots"
    assert main(["plot", "-f", str(npz.parents[2]), "-o", str(plots)]) == 2
    assert str(npz) in capsys.readouterr().err and not list(plots.glob("*.png"))


def test_a_broken_ffmpeg_is_one_message(run, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("IMAGEIO_FFMPEG_EXE", "/bin/false")
    assert main(["record-video", "-f", str(run), "-o", str(tmp_path / "v.mp4")]) == 1
    assert "with ffmpeg" in capsys.readouterr().err and not (tmp_path / "v.mp4").exists()


@pytest.mark.parametrize(
    "results",
    [
        "not json",
        json.dumps({"env_id": ENV}),
        json.dumps({"algo": "a/b", "env_id": ENV}),
        json.dumps({"algo": "ma2c", "env_id": "../../x"}),
    ],
)
def test_a_hub_repo_with_bad_results_is_one_message(results, tmp_path):
    from sb3_marl.hub import HubError, _place_run

    snapshot = tmp_path / "snapshot"
    snapshot.mkdir()
    (snapshot / "results.json").write_text(results)
    with pytest.raises(HubError, match=r"results\.json"):
        _place_run("org/name", snapshot, tmp_path / "logs")
    assert not (tmp_path / "logs").exists()


@pytest.mark.parametrize(
    ("action", "match"),
    [(3.9, "Invalid action 3.9"), ("2", "Invalid action '2'"), (None, "Invalid action None"), (7, "Invalid action 7")],
)
def test_pettingzoo_step_rejects_bad_actions(action, match):
    from sb3_marl.envs.parallel import parallel_env

    env = parallel_env(density=1, n_avs=2)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=match):
        env.step({"av_0": action, "av_1": 1})
    with pytest.raises(ValueError, match="unknown agent"):
        env.step({"av_0": 1, "av_1": 1, "av_9": 1})


def test_stepping_after_the_end_raises():
    import gymnasium as gym

    from wrappers import ParameterSharingVecEnv

    env = gym.make(ENV, config={"n_avs": 1, "duration": 1}).unwrapped
    env.reset(seed=0)
    done = False
    while not done:
        _, _, terminated, truncated, _ = env.step(np.array([1]))
        done = terminated or truncated
    with pytest.raises(RuntimeError, match="call reset"):
        env.step(np.array([1]))
    for backend in ("dummy", "subproc"):
        venv = ParameterSharingVecEnv(ENV, vec_backend=backend, seed=0)
        venv.reset()
        venv.close()
        with pytest.raises(RuntimeError, match="closed"):
            venv.step(np.ones(venv.num_envs, dtype=np.int64))


def test_a_foreign_checkpoint_resumes_its_replay_buffer_as_data_never_its_pickle(tmp_path, capsys):
    """A checkpoint folder from someone else (the benchmark's layout: model.zip with
    replay_buffer.npz beside it, and a poisoned replay_buffer.pkl) continues training with the
    arrays read as data; the pickle is never opened. Without the npz, the pickle is refused with a
    message; an npz whose arrays do not fit the model's buffer is named."""
    import pickle

    from sb3_marl.common.files import REPLAY_BUFFER_FILE, read_replay_buffer, write_replay_buffer

    argv = ["train", "--algo", "madqn", "-n", "400", "--eval-freq", "1000", "--eval-episodes", "1"]
    assert main([*argv, "-f", str(tmp_path / "own"), "-params", "learning_starts:100", "buffer_size:2000"]) == 0
    run = tmp_path / "own" / "madqn" / f"{ENV_NAME}_1"
    model = get_algo("madqn").load(run / f"{ENV_NAME}.zip")
    checkpoint = tmp_path / "foreign"
    checkpoint.mkdir()
    marker = tmp_path / "marker"
    (checkpoint / "replay_buffer.pkl").write_bytes(pickle.dumps(Payload(marker)))
    (checkpoint / "model.zip").write_bytes((run / f"{ENV_NAME}.zip").read_bytes())
    buffer = get_algo("madqn")("MlpPolicy", "CartPole-v1", buffer_size=50, learning_starts=0).replay_buffer
    buffer.observations[:] = 1.5
    buffer.pos, buffer.full = 7, True
    write_replay_buffer(buffer, checkpoint / REPLAY_BUFFER_FILE)
    again = get_algo("madqn")("MlpPolicy", "CartPole-v1", buffer_size=50, learning_starts=0).replay_buffer
    read_replay_buffer(again, checkpoint / REPLAY_BUFFER_FILE)
    assert (again.observations == 1.5).all() and (again.pos, again.full) == (7, True)
    # the madqn run's buffer has other sizes
    with pytest.raises(ValueError, match=r"array 'actions' is int64 \(50, 1, 1\).*expects"):
        read_replay_buffer(model.replay_buffer, checkpoint / REPLAY_BUFFER_FILE)
    (checkpoint / REPLAY_BUFFER_FILE).unlink()
    assert main([*argv, "-f", str(tmp_path / "continued"), "-i", str(checkpoint / "model.zip")]) == 0
    assert "Not loading" in capsys.readouterr().out and not marker.exists()


@pytest.mark.parametrize("output", ["/dev/full", "{tmp}", "{tmp}/missing/and/more/eval.json"])
def test_unusable_evaluate_outputs_are_refused_before_the_evaluation(run, tmp_path, capsys, output):
    """-o naming a device or a folder: exit 2 naming the flag, before any episode runs; a missing
    folder is created and the file written whole."""
    output = output.format(tmp=tmp_path)
    code = main(["evaluate", "-f", str(run), "--eval-episodes", "1", "-o", output])
    if output.endswith(".json"):
        assert code == 0 and json.loads(Path(output).read_text())["episodes"] == 1
        return
    assert code == 2
    err = capsys.readouterr().err
    assert "-o/--output" in err and ("not a regular file" in err or "is a folder" in err)


@pytest.mark.parametrize(
    ("argv", "flag"),
    [
        (["train", "--n-envs", "1000000000"], "--n-envs"),
        (["train", "--eval-episodes", "1000000000"], "--eval-episodes"),
        (["baselines", "--eval-episodes", "1000000000"], "--eval-episodes"),
        (["train", "-params", "n_copies:100000"], "n_copies"),
    ],
)
def test_sizes_that_allocate_are_bounded_before_any_folder(argv, flag, tmp_path, capsys):
    try:
        code = main([*argv, "-f" if argv[0] == "train" else "-o", str(tmp_path / "out")])
    except SystemExit as error:  # argparse's own exit for a flag's type
        code = error.code
    assert code == 2
    err = capsys.readouterr().err
    assert flag in err and ("<= 256" in err or "<= 100,000" in err)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("content", ["[1, 2]", "{}", '{"trial": {"algo": "ma2c"'])
def test_malformed_benchmark_files_are_named_by_every_benchmark_command(tmp_path, capsys, content):
    """A result.json that is a list, empty or truncated, and a corrupt benchmark.json: status,
    report and evaluate name the file, no traceback."""
    grid = Path(__file__).resolve().parents[2] / "results" / "paper-grid"
    copy = tmp_path / "grid"
    (copy / "trials").mkdir(parents=True)
    (copy / "benchmark.json").write_text((grid / "benchmark.json").read_text())
    trial = copy / "trials" / "ma2c_density1_default_seed0"
    subprocess.run(["cp", "-r", str(grid / "trials" / trial.name), str(trial)], check=True)
    (trial / "result.json").write_text(content)
    status = ["benchmark", "status", "--grid", "reward", "--seeds", "1", "--densities", "1", "-f", str(copy)]
    assert main(status) == 1
    assert re.search(r"ma2c_density1_default_seed0 +unreadable", capsys.readouterr().out)
    assert main(["benchmark", "evaluate", "-f", str(copy)]) == 1  # a damaged trial, as status says: named, left to repair
    assert str(trial / "result.json") in capsys.readouterr().err
    (trial / "result.json").write_text((grid / "trials" / trial.name / "result.json").read_text())
    (copy / "benchmark.json").write_text('{"budget": ')
    for argv in (status, ["benchmark", "report", "-f", str(copy), "-o", str(tmp_path / "out")]):
        assert main(argv) == 2
        assert str(copy / "benchmark.json") in capsys.readouterr().err


def test_a_model_of_another_observation_is_named_by_every_command(run, tmp_path, capsys):
    """A run whose model zip observes 6 features (obs_target_speed) where its scenario config shows
    5: evaluate, record-video and push-to-hub --dry-run name the model and both shapes."""
    other = tmp_path / "other"
    assert (
        main(["train", "-f", str(other), *TINY[:-2], "-params", "n_steps:20", "env_config:dict(obs_target_speed=True)"]) == 0
    )
    logs = tmp_path / "logs"
    subprocess.run(["cp", "-r", str(run), str(logs)], check=True)
    model = logs / "ma2c" / f"{ENV_NAME}_1" / f"{ENV_NAME}.zip"
    model.write_bytes((other / "ma2c" / f"{ENV_NAME}_1" / f"{ENV_NAME}.zip").read_bytes())
    capsys.readouterr()
    for argv in (
        ["evaluate", "--eval-episodes", "1"],
        ["record-video"],
        ["push-to-hub", "-orga", "me", "--dry-run", str(tmp_path / "hub")],
    ):
        assert main([*argv, "-f", str(logs)]) == 2
        err = capsys.readouterr().err
        assert str(model) in err and "(5, 6) per AV" in err and "(5, 5)" in err


def test_continuing_from_a_model_of_another_observation_is_refused_before_any_folder(run, tmp_path, capsys):
    model = run / "ma2c" / f"{ENV_NAME}_1" / f"{ENV_NAME}.zip"
    argv = ["train", "-f", str(tmp_path / "logs"), "-i", str(model), *TINY[:-2]]
    assert main([*argv, "-params", "n_steps:20", "env_config:dict(obs_vehicles_count=7)"]) == 2
    err = capsys.readouterr().err
    assert "-i/--trained-agent" in err and "(5, 5) per AV" in err and "(7, 5)" in err
    broken = tmp_path / "broken.zip"
    with zipfile.ZipFile(model) as source, zipfile.ZipFile(broken, "w") as target:
        for item in source.namelist():
            target.writestr(item, source.read(item)[:40] if item.endswith(".pth") else source.read(item))
    assert main(["train", "-f", str(tmp_path / "logs"), "-i", str(broken), *TINY]) == 2
    assert "-i/--trained-agent" in capsys.readouterr().err
    assert not (tmp_path / "logs").exists()


def test_continuing_names_a_network_mismatch_and_notes_a_density_change(run, tmp_path, capsys):
    """-i of a shared-network model with architecture:separate: refused before any folder, naming
    both; -i of a density-1 model on density 2: trained, with a note that it is a curriculum."""
    model = run / "ma2c" / f"{ENV_NAME}_1" / f"{ENV_NAME}.zip"
    argv = ["train", "-i", str(model), *TINY[:-2]]
    assert main([*argv, "-f", str(tmp_path / "a"), "-params", "n_steps:20", "architecture:separate"]) == 2
    err = capsys.readouterr().err
    assert "has the shared actor-critic network" in err and "architecture: separate" in err
    assert not (tmp_path / "a").exists()
    assert main([*argv, "-f", str(tmp_path / "b"), "--env", "sb3_marl/LaneChange-density2-v0", "-params", "n_steps:20"]) == 0
    assert f"the model was trained on {ENV}; training continues on sb3_marl/LaneChange-density2-v0" in capsys.readouterr().out
