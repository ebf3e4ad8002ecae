"""push-to-hub / load-from-hub: the folder built for real, its model card parsed back by
huggingface_hub, upload and download through huggingface_hub's client with only HTTP replaced."""

import json
import shutil
import sys
from pathlib import Path

import httpx2
import huggingface_hub
import numpy as np
import pytest
import yaml
from huggingface_hub import ModelCard, metadata_load
from huggingface_hub.utils._http import default_client_factory

from sb3_marl.algos.a2c import MaskableA2C
from sb3_marl.cli import main
from sb3_marl.common.files import read_run_yaml

sys.path.insert(0, str(Path(__file__).parent))
from fake_hub import FakeHub

ENV_NAME = "sb3_marl-LaneChange-density1-v0"
MODEL = f"ma2c-{ENV_NAME}.zip"
FILES = {"README.md", "config.yml", "config.json", "results.json", "trips.csv", "replay.mp4", MODEL}


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("logs")
    assert main(["train", "-f", str(folder), "-n", "240", "--eval-freq", "-1", "-params", "n_steps:20", "--verbose", "0"]) == 0
    return folder


@pytest.fixture
def hub(monkeypatch, tmp_path) -> FakeHub:
    # a cache of our own: the fake Hub's fixed commit hash must never meet files cached by another test run
    monkeypatch.setattr(huggingface_hub.constants, "HF_HUB_CACHE", str(tmp_path / "hf_cache"))
    # large files through LFS over HTTP: hf_xet's transfer runs outside the replaced HTTP boundary
    monkeypatch.setattr(huggingface_hub.constants, "HF_HUB_DISABLE_XET", True)
    fake = FakeHub()
    huggingface_hub.set_client_factory(fake.client)
    monkeypatch.setenv("HF_TOKEN", "hf_test_token")
    yield fake
    huggingface_hub.set_client_factory(default_client_factory)
    huggingface_hub.close_session()


def test_dry_run_builds_the_folder_with_a_model_card_matching_the_evaluation(logs, tmp_path):
    folder = tmp_path / "card"
    assert main(["push-to-hub", "-f", str(logs), "-orga", "me", "--eval-episodes", "3", "--dry-run", str(folder)]) == 0
    # a dry run needs no organisation: the card names a placeholder
    assert main(["push-to-hub", "-f", str(logs), "--eval-episodes", "1", "--no-video", "--dry-run", str(tmp_path / "x")]) == 0
    assert "your-organization/" in (tmp_path / "x" / "README.md").read_text()
    assert {p.name for p in folder.iterdir()} == FILES
    results = json.loads((folder / "results.json").read_text())
    assert results["episodes"] == 3 and results["num_timesteps"] == 240

    card = ModelCard.load(folder / "README.md")
    assert card.data.library_name == "stable-baselines3" and "sb3_marl/LaneChange-density1-v0" in card.data.tags
    metrics = {r.metric_type: r.metric_value for r in card.data.eval_results}
    assert metrics["mean_reward"] == f"{results['return_mean']:.2f} +/- {results['return_std']:.2f}"
    assert metrics["collision_rate"] == pytest.approx(results["collision_rate"], abs=1e-4)
    assert metrics["mean_speed_m_per_s"] == pytest.approx(results["speed_mean"], abs=1e-4)
    assert metrics["acceleration_std_m_per_s2"] == pytest.approx(results["acceleration_std"], abs=1e-4)
    assert all(r.dataset_type == "sb3_marl/LaneChange-density1-v0" for r in card.data.eval_results)
    assert all(r.metric_name == r.metric_type for r in card.data.eval_results)  # huggingface_sb3's naming
    assert "sampled actions (the authors' protocol)" in card.text  # the protocol behind the numbers
    assert metadata_load(folder / "README.md")["model-index"][0]["name"] == "MA2C-sb3_marl/LaneChange-density1-v0"
    assert "@article{zhou2022multi" in card.text and "sb3-marl load-from-hub --repo-id me/ma2c-" in card.text
    assert MaskableA2C.load(folder / MODEL).num_timesteps == 240
    # the traffic view: a table of both protocols on the card, every vehicle's trip beside it
    assert "## Traffic" in card.text and f"| on | {results['traffic']['flow_veh_h']:.0f} |" in card.text
    trips = (folder / "trips.csv").read_text().splitlines()
    assert trips[0].startswith("supervisor,seed,id,vType") and {line.split(",")[0] for line in trips[1:]} == {"on", "off"}


def test_push_then_load_round_trip(logs, tmp_path, hub, capsys):
    assert (
        main(
            [
                "push-to-hub",
                "-f",
                str(logs),
                "-orga",
                "me",
                "--repo-name",
                "lane",
                "--eval-episodes",
                "2",
                "-m",
                "first upload",
            ]
        )
        == 0
    )
    assert set(hub.repos["me/lane"]) == FILES
    # the model and the video go through LFS (uploaded, verified, committed by sha256), as on the real Hub
    assert hub.lfs_paths["me/lane"] == {MODEL, "replay.mp4"}
    assert sum(method == "PUT" and path.startswith("/lfs-upload/me/lane/") for method, path in hub.requests) == 2
    assert hub.commits[-1]["summary"] == "first upload"
    assert "uploaded to https://huggingface.co/me/lane/commit/" in capsys.readouterr().out
    built = next(logs.glob(f"ma2c/{ENV_NAME}_1/hub"))
    assert hub.repos["me/lane"][MODEL] == (built / MODEL).read_bytes()

    downloaded = tmp_path / "downloaded"
    assert main(["load-from-hub", "--repo-id", "me/lane", "-f", str(downloaded)]) == 0
    run = downloaded / "ma2c" / f"{ENV_NAME}_1"
    assert (run / f"{ENV_NAME}.zip").read_bytes() == hub.repos["me/lane"][MODEL]
    assert (run / ENV_NAME / "config.yml").is_file()
    # the downloaded run is evaluated like a trained one, with the same numbers as the original
    for folder, out in ((downloaded, "a.json"), (logs, "b.json")):
        assert main(["enjoy", "-f", str(folder), "--exp-id", "1", "--eval-episodes", "2", "-o", str(tmp_path / out)]) == 0
    a, b = (json.loads((tmp_path / out).read_text()) for out in ("a.json", "b.json"))
    np.testing.assert_array_equal(a["returns"], b["returns"])

    # the card's Python usage snippet runs as written, downloading from the (fake) Hub
    card = hub.repos["me/lane"]["README.md"].decode()
    snippet = card.split("```python\n", 1)[1].split("```", 1)[0]
    exec(compile(snippet, "README.md", "exec"), {})
    assert "episode returns: [" in capsys.readouterr().out


def test_missing_token_keeps_the_built_folder(logs, tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("HF_TOKEN", raising=False)
    monkeypatch.delenv("HUGGING_FACE_HUB_TOKEN", raising=False)
    monkeypatch.setattr(huggingface_hub.constants, "HF_TOKEN_PATH", str(tmp_path / "no_token"))
    assert main(["push-to-hub", "-f", str(logs), "-orga", "me", "--eval-episodes", "1", "--no-video"]) == 1
    err = capsys.readouterr().err
    assert "No Hugging Face token" in err and "HF_TOKEN" in err
    built = logs / "ma2c" / f"{ENV_NAME}_1" / "hub"
    assert (built / "README.md").is_file() and (built / MODEL).is_file()


def test_network_errors_are_reported_clearly(logs, tmp_path, hub, capsys):
    hub.fail_with = httpx2.ConnectError("Name or service not known")
    assert main(["push-to-hub", "-f", str(logs), "-orga", "me", "--eval-episodes", "1", "--no-video"]) == 1
    err = capsys.readouterr().err
    assert "Upload of" in err and "failed" in err and "stays in" in err
    assert (logs / "ma2c" / f"{ENV_NAME}_1" / "hub" / "README.md").is_file()

    assert main(["load-from-hub", "--repo-id", "me/lane", "-f", str(tmp_path)]) == 1
    assert "Download of me/lane failed" in capsys.readouterr().err
    assert not (tmp_path / "ma2c").exists()


def test_load_from_hub_of_a_missing_repo(tmp_path, hub, capsys):
    assert main(["load-from-hub", "--repo-id", "me/nothing", "-f", str(tmp_path)]) == 1
    assert "Download of me/nothing failed" in capsys.readouterr().err


def test_the_upload_holds_only_the_files_built_for_it(logs, tmp_path, hub):
    """Leftovers in <run>/hub (a .env, a link to a file outside the run) and <run>/hub itself a
    link to an outside folder: the upload holds the built files only, and nothing is written
    outside the run."""
    run_hub = logs / "ma2c" / f"{ENV_NAME}_1" / "hub"
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "secret.txt").write_text("token")
    run_hub.mkdir(exist_ok=True)
    (run_hub / ".env").write_text("HF_TOKEN=secret")
    (run_hub / "linked.txt").symlink_to(outside / "secret.txt")
    argv = ["push-to-hub", "-f", str(logs), "-orga", "me", "--eval-episodes", "1", "--no-video"]
    assert main([*argv, "--repo-name", "clean"]) == 0
    assert set(hub.repos["me/clean"]) == FILES - {"replay.mp4"}
    shutil.rmtree(run_hub)
    run_hub.symlink_to(outside, target_is_directory=True)
    assert main([*argv, "--repo-name", "clean2"]) == 0
    assert set(hub.repos["me/clean2"]) == FILES - {"replay.mp4"}
    assert sorted(p.name for p in outside.iterdir()) == ["secret.txt"] and not run_hub.is_symlink()
    (tmp_path / "link").symlink_to(tmp_path / "empty", target_is_directory=True)
    (tmp_path / "empty").mkdir()
    assert main(["push-to-hub", "-f", str(logs), "-orga", "me", "--dry-run", str(tmp_path / "link")]) == 2


@pytest.mark.parametrize("linked", [True, False])
def test_a_config_with_a_secret_never_reaches_the_upload(logs, tmp_path, capsys, linked):
    """<run>/<env>/config.yml a link to a secret file outside the run, or a copy of the run's config
    with foreign keys added: refused with one message naming the file; nothing built holds the secret."""
    config = logs / "ma2c" / f"{ENV_NAME}_1" / ENV_NAME / "config.yml"
    original = config.read_text()
    secret = tmp_path / "secret.yml"
    hyperparams = read_run_yaml(config)  # rl-zoo's ordered pairs, as plain data
    secret.write_text(yaml.safe_dump({**hyperparams, "hf_token": "hf_SECRET", "password": "hunter2"}))
    config.unlink()
    if linked:
        config.symlink_to(secret)
    else:
        config.write_text(secret.read_text())
    try:
        argv = ["push-to-hub", "-f", str(logs), "-orga", "me", "--eval-episodes", "1", "--no-video", "--dry-run"]
        assert main([*argv, str(tmp_path / "built")]) == 2
    finally:
        config.unlink()
        config.write_text(original)
    err = capsys.readouterr().err
    assert str(config) in err and ("outside" in err if linked else "hf_token" in err) and "Traceback" not in err
    assert not any("hf_SECRET" in p.read_text(errors="ignore") for p in tmp_path.rglob("*") if p.is_file() and p != secret)


def test_a_repo_with_a_file_name_leaving_the_folder_is_one_message(logs, tmp_path, hub, capsys):
    """A hostile repo whose file list names ``../outside.txt``: one message, nothing written outside."""
    assert (
        main(["push-to-hub", "-f", str(logs), "-orga", "me", "--repo-name", "evil", "--eval-episodes", "1", "--no-video"]) == 0
    )
    hub.repos["me/evil"]["../outside.txt"] = b"written outside"
    assert main(["load-from-hub", "--repo-id", "me/evil", "-f", str(tmp_path / "downloaded")]) == 1
    err = capsys.readouterr().err
    assert "Download of me/evil failed" in err and "Traceback" not in err
    assert not list(tmp_path.rglob("outside.txt")) and not (tmp_path.parent / "outside.txt").exists()


def test_push_to_hub_of_a_model_that_needs_trust_builds_with_the_flag(logs, tmp_path, capsys):
    """A model whose learning-rate schedule is a pickled function (SB3 saves any callable so) needs
    --trust-remote-code: refused without it, the folder built with it (the flag is not asked for
    again while building)."""
    from sb3_marl.envs import ENV_IDS
    from wrappers import ParameterSharingVecEnv

    run = tmp_path / "logs" / "ma2c" / f"{ENV_NAME}_1"
    shutil.copytree(logs / "ma2c" / f"{ENV_NAME}_1", run)
    model = MaskableA2C("MlpPolicy", ParameterSharingVecEnv(ENV_IDS[1], seed=0), n_steps=20, learning_rate=lambda p: 5e-4 * p)
    model.save(run / f"{ENV_NAME}.zip")
    argv = ["push-to-hub", "-f", str(tmp_path / "logs"), "-orga", "me", "--eval-episodes", "1", "--no-video"]
    assert main([*argv, "--dry-run", str(tmp_path / "refused")]) == 2
    assert "trust_remote_code" in capsys.readouterr().err
    with pytest.warns(UserWarning, match="trust_remote_code=True"):
        assert main([*argv, "--trust-remote-code", "--dry-run", str(tmp_path / "built")]) == 0
    assert (tmp_path / "built" / "README.md").is_file()
