"""What keeping a grid in a storage URI costs a trial (issue 59), on one machine: the same tiny
grid (the ``reward`` experiment at density 1, one seed: two MA2C trials, one CPU each) run into a
local folder, into ``file://`` storage and into S3 (moto's server on localhost), each in a fresh
folder; prints each run's wall time and, per trial, the seconds its transfers took and the bytes
they moved (``result.json``'s ``storage``, every transfer but the last upload).

    python benchmarks/storage_overhead.py [--budget 0.003]
"""

from __future__ import annotations

import argparse
import os
import socket
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

from sb3_marl.benchmark.runner import run_benchmark
from sb3_marl.benchmark.storage import GridStorage


def s3_server() -> str:
    """moto's S3 server on a free localhost port, its bucket ``grid``; the environment set for it."""
    import boto3
    from moto.server import ThreadedMotoServer

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False).start()
    os.environ.update(
        AWS_ACCESS_KEY_ID="testing",
        AWS_SECRET_ACCESS_KEY="testing",
        AWS_DEFAULT_REGION="us-east-1",
        AWS_ENDPOINT_URL=f"http://127.0.0.1:{port}",
    )
    boto3.client("s3").create_bucket(Bucket="grid")
    return "s3://grid/overhead"


def main() -> None:
    import logging

    import ray

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budget", type=float, default=0.003, help="fraction of 1M env steps per trial (default: 0.003)")
    args = parser.parse_args()
    logging.getLogger("werkzeug").setLevel(logging.WARNING)
    root = Path(tempfile.mkdtemp(prefix="storage-overhead-"))
    storages = {"local folder": None, "file://": f"file://{root}/storage", "s3 (moto)": s3_server()}
    ray.init(num_cpus=2, include_dashboard=False, configure_logging=False, log_to_driver=False)
    for name, uri in storages.items():
        start = time.perf_counter()
        outcome = run_benchmark("reward", root / name.split()[0], args.budget, 1, (1,), 1, 3, verbose=0, storage=uri)
        wall = time.perf_counter() - start
        print(f"{name}: {len(outcome.completed)} trials in {wall:.1f} s (wall, Ray's start excluded)", flush=True)
        for trial in sorted(outcome.completed):
            if uri is None:
                continue
            result = GridStorage(uri).read_json_object(f"trials/{trial}/result.json") or {}
            sync = result["storage"]
            print(
                f"  {trial}: trained {result['wall_time_s']:.1f} s, transfers {sync['sync_s']:.2f} s, "
                f"{sync['bytes'] / 1e6:.2f} MB",
                flush=True,
            )
    ray.shutdown()


if __name__ == "__main__":
    main()
