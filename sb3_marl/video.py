"""Headless mp4 of evaluation episodes, drawn by highway-env's renderer and encoded by
imageio-ffmpeg (its wheel ships the ffmpeg binary: nothing is downloaded at run time)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import imageio.v2 as imageio
import numpy as np
from tqdm import tqdm

from sb3_marl.envs import copy_av_counts, make_scenario
from sb3_marl.evaluation import Policy, run_episodes
from sb3_marl.files import replaced_atomically


def record_video(
    policy: Policy,
    env_id: str,
    path: str | Path,
    n_episodes: int = 1,
    seed: int = 0,
    config: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Play ``n_episodes`` seeded episodes (cycling through the density's AV counts) and write them
    to the mp4 ``path``, one frame per policy step (5 Hz, played at 5 fps: real time).

    :return: ``{"path", "frames", "episodes", "fps"}``
    """
    path = Path(path)
    counts = copy_av_counts(env_id, config, n_episodes)
    frames: list[np.ndarray | None] = []
    fps = None
    for episode, n_avs in enumerate(tqdm(counts, desc="recording", unit="episode", leave=False)):
        env = make_scenario(env_id, {**(config or {}), "n_avs": n_avs}, render_mode="rgb_array")
        fps = env.config["policy_frequency"]
        run_episodes(env, policy, 1, seed + episode, on_step=lambda env, info: frames.append(env.render()))
        env.close()
    # libx264 needs even frame sizes; macro_block_size=2 pads odd ones instead of rescaling
    with (
        replaced_atomically(path) as temporary,
        imageio.get_writer(temporary, fps=fps, codec="libx264", macro_block_size=2, format="FFMPEG") as writer,
    ):
        for frame in frames:
            writer.append_data(frame)  # type: ignore[attr-defined]
    return {"path": str(path), "frames": len(frames), "episodes": n_episodes, "fps": fps}


__all__ = ["record_video"]
