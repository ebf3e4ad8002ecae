"""The grid on a two-node Ray cluster whose nodes share no disk (issue 59): a Ray head and a second
Ray node on this machine as separate processes (one CPU each), an S3 server on localhost (moto's),
and a tiny grid launched with ``--storage s3://...``: each node runs a trial, the second node is
killed mid-trial and its trial finishes on the head from the checkpoint in the storage, and
``status`` and ``report`` on the head see every trial through the storage."""

from __future__ import annotations

import json
import logging
import os
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

pytest.importorskip("ray")
pytest.importorskip("moto.server")

BUCKET, GRID = "grid", "tiny"
TRIALS = ["ma2c_density1_default_seed0", "ma2c_density1_global-reward_seed0"]


@pytest.fixture
def s3(monkeypatch):
    """moto's S3 server on a free localhost port; the credentials and endpoint in the environment
    (where the Ray nodes started after it find them, as on a cloud VM)."""
    from moto.server import ThreadedMotoServer

    logging.getLogger("werkzeug").setLevel(logging.WARNING)  # no line per request
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
    server.start()
    environment = {
        "AWS_ACCESS_KEY_ID": "testing",
        "AWS_SECRET_ACCESS_KEY": "testing",
        "AWS_DEFAULT_REGION": "us-east-1",
        "AWS_ENDPOINT_URL": f"http://127.0.0.1:{port}",
    }
    for key, value in environment.items():
        monkeypatch.setenv(key, value)
    import boto3

    client = boto3.client("s3")
    client.create_bucket(Bucket=BUCKET)
    yield client
    server.stop()


def _stored(client, key: str) -> bytes | None:
    try:
        return client.get_object(Bucket=BUCKET, Key=f"{GRID}/{key}")["Body"].read()
    except client.exceptions.NoSuchKey:
        return None


def test_a_two_node_grid_keeps_everything_in_the_storage(s3, tmp_path, monkeypatch):
    from ray.cluster_utils import Cluster

    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1}, connect=False)
    worker = cluster.add_node(num_cpus=1)
    head_id = cluster.head_node.node_id
    launcher = tmp_path / "launcher"
    command = [sys.executable, "-m", "sb3_marl", "benchmark", "--grid", "reward", "--densities", "1", "--seeds", "1"]
    status_command = [*command[:4], "status", *command[4:]]
    command += ["--budget", "0.003", "--eval-every", "1", "--max-failures", "2", "--verbose", "0"]
    command += ["--address", cluster.address, "--storage", f"s3://{BUCKET}/{GRID}", "-f", str(launcher)]
    try:
        run = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=os.environ.copy())
        # the trial on the second node: killed once it has a checkpoint in the storage
        killed, deadline = None, time.monotonic() + 240
        while killed is None and time.monotonic() < deadline and run.poll() is None:
            for trial in TRIALS:
                info = _stored(s3, f"trials/{trial}/trial.json")
                if info and json.loads(info)["attempts"][-1].get("node") == worker.node_id:
                    cluster.remove_node(worker)
                    killed = trial
                    break
            time.sleep(0.2)
        output = run.communicate(timeout=300)[0]
    finally:
        cluster.shutdown()
    assert killed is not None, output[-3000:]
    assert run.returncode == 0, output[-3000:]
    assert "2 trials completed, 0 skipped (finished before), 0 failed" in output
    assert not (launcher / "trials").exists()  # nothing of the trials went through the launcher's folder
    finished_at = {}
    for trial in TRIALS:
        attempts = json.loads(_stored(s3, f"trials/{trial}/trial.json"))["attempts"]
        result = json.loads(_stored(s3, f"trials/{trial}/result.json"))
        assert result["num_timesteps"] >= 6_000  # the budget's 6,000 AV-steps, in whole rollouts
        finished_at[trial] = result["num_timesteps"]
        assert result["storage"]["uri"] == f"s3://{BUCKET}/{GRID}" and result["storage"]["bytes"] > 100_000
        if trial == killed:  # restarted on the head from the stored checkpoint
            assert [a["node"] for a in attempts] == [worker.node_id, head_id]
            resumed_at = attempts[1]["resumed_at_timesteps"]
            assert resumed_at > 0
        else:
            assert [a["node"] for a in attempts] == [head_id]
    # the head reads the grid from the storage: status, and the evaluation history kept across the restart
    copy = tmp_path / "copy"
    status = subprocess.run(
        [*status_command, "--storage", f"s3://{BUCKET}/{GRID}", "-f", str(copy)],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert "downloaded 2 trial folders" in status and "2 of 2 trials finished" in status
    evaluations = np.load(next((copy / "trials" / killed).glob("ma2c/*_1/evaluations.npz")))
    assert np.all(np.diff(evaluations["timesteps"]) > 0) and evaluations["timesteps"][0] <= resumed_at
    assert evaluations["timesteps"][-1] == finished_at[killed]
    assert not list(copy.rglob("checkpoints"))  # the checkpoints stay in the storage
    assert b"testing" not in b"".join(path.read_bytes() for path in copy.rglob("*") if path.is_file())
    # and the report, from a fresh copy of the storage
    report = subprocess.run(
        [*command[:4], "report", "--storage", f"s3://{BUCKET}/{GRID}", "-f", str(tmp_path / "c"), "-o", str(tmp_path / "out")],
        capture_output=True,
        text=True,
    )
    assert report.returncode == 0, report.stderr[-2000:]
    table = (tmp_path / "out" / "paper_table.md").read_text()
    assert "| local reward | 1 | 1 |" in table and "| global reward | 1 | 1 |" in table
