"""Headless mp4 of evaluation episodes, drawn by highway-env's renderer and encoded by
imageio-ffmpeg (its wheel ships the ffmpeg binary: nothing is downloaded at run time).

Each frame shows the road around the AVs (the camera follows the centre of the AVs still on the
road and zooms out until all of them are in view, from :data:`SCALING` px/m, a 5 m vehicle 40 px
long, down to the whole road; each AV labelled with its index), under a band with the time, a legend
of the colours (highway-env's: AVs green, HDVs blue, crashed vehicles red) and, per AV, its speed
and meta-action; an action the safety supervisor replaced shows both, highlighted, and a crash is
marked. The video ends with the episode (at the latest when the last AV leaves the road).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, ImageDraw
from tqdm import tqdm

from sb3_marl.common.files import replaced_atomically
from sb3_marl.envs import av_counts, make_scenario
from sb3_marl.envs.lane_change_env import ACTIONS, LaneChangeEnv
from sb3_marl.evaluation.episodes import Policy, run_episodes
from sb3_marl.sim import kernel


class VideoExtraMissing(ImportError):
    """Videos need the ``video`` extra (imageio and imageio-ffmpeg), not installed."""


def imageio_module() -> Any:
    """imageio's v2 API with imageio-ffmpeg's ffmpeg, or :class:`VideoExtraMissing` saying how to get them."""
    try:
        import imageio.v2 as imageio
        import imageio_ffmpeg  # noqa: F401  # imageio's FFMPEG format finds its binary
    except ImportError as error:
        raise VideoExtraMissing(
            f"videos need the video extra ({error.name} is not installed): pip install 'sb3-marl[video]' "
            "(imageio, and imageio-ffmpeg, whose wheel carries ffmpeg)"
        ) from None
    return imageio


#: The video's view of the road: width and height [px], the largest scale [px/m] (a 5 m vehicle
#: 40 px long) and the smallest (the whole 520 m road in view).
WIDTH, HEIGHT, SCALING, MIN_SCALING = 1200, 240, 8.0, 2.0
VIEW = {"screen_width": WIDTH, "screen_height": HEIGHT, "scaling": SCALING, "centering_position": [0.5, 0.5]}
#: Margin [px] kept between the outermost AVs and the frame's edges; share of the way to the
#: target zoom the camera moves per frame (smooth zooming).
MARGIN, ZOOM_RATE = 80, 0.25
#: Height [px] of the text band above the road; one line per AV after the header.
LINE = 18
COLOURS = {
    "text": (20, 20, 20),
    "label": (255, 255, 255),
    "intervened": (200, 90, 0),
    "crashed": (200, 0, 0),
    "band": (245, 245, 245),
}


class _Camera:
    """highway-env's viewer follows ``observer_vehicle.position``: here the centre [m] of the AVs
    still on the road (all AVs once none is), zoomed so that every one of them is in the frame
    (between :data:`MIN_SCALING` and :data:`SCALING` px/m; zooming out at once, in smoothly)."""

    def __init__(self, env: LaneChangeEnv) -> None:
        self.env = env
        self.scaling: float | None = None

    def _rows(self) -> np.ndarray:
        avs = self.env.state[: self.env.n_avs]
        on_road = avs[avs[:, kernel.COLLIDABLE] > 0]
        return on_road if len(on_road) else avs

    @property
    def position(self) -> np.ndarray:
        rows = self._rows()
        return np.array([(rows[:, kernel.X].min() + rows[:, kernel.X].max()) / 2, rows[:, kernel.Y].mean()])

    def zoom(self) -> float:
        """The scale [px/m] of the next frame: toward the one that frames every AV on the road."""
        spread = np.ptp(self._rows()[:, kernel.X]) + 2 * kernel.LENGTH
        target = float(np.clip((WIDTH - 2 * MARGIN) / spread, MIN_SCALING, SCALING))
        if self.scaling is None or target < self.scaling:  # out at once (no AV leaves the frame), in smoothly
            self.scaling = target
        else:
            self.scaling += ZOOM_RATE * (target - self.scaling)
        return self.scaling


def frame(env: LaneChangeEnv, info: dict[str, Any], rows: int | None = None) -> np.ndarray:
    """The road around the AVs under a band with the time, the legend and each AV's speed and
    meta-action (see the module doc), as an RGB array; ``rows``: AV lines the band has room for
    (default: this episode's AVs; a video of several AV counts gives every frame the same size)."""
    if env.viewer is None:
        env.render()  # highway-env creates its viewer on the first frame
    assert env.viewer is not None, "the env renders rgb_array frames"
    if not isinstance(env.viewer.observer_vehicle, _Camera) or env.viewer.observer_vehicle.env is not env:
        env.viewer.observer_vehicle = _Camera(env)
    env.viewer.sim_surface.scaling = env.viewer.observer_vehicle.zoom()
    pixels = env.render()
    assert pixels is not None
    road = Image.fromarray(pixels)
    labels = ImageDraw.Draw(road)
    for i, (x, y) in enumerate(env.state[: env.n_avs, [kernel.X, kernel.Y]]):
        px, py = env.viewer.sim_surface.pos2pix(x, y)
        labels.text((px - 8, py - 22), f"AV {i}", fill=COLOURS["crashed" if info["crashed"][i] else "label"])
    n = env.n_avs
    band = Image.new("RGB", (road.width, LINE * (max(rows or 0, n) + 1) + 6), COLOURS["band"])
    draw = ImageDraw.Draw(band)
    time = info["step"] / env.config["policy_frequency"]
    header = f"t = {time:4.1f} s    legend: AV green, HDV blue, crashed red    ({n} AVs, {env.n_hdvs} HDVs)"
    draw.text((8, 4), header, fill=COLOURS["text"])
    for i in range(n):
        proposed, executed = int(info["proposed_action"][i]), int(info["executed_action"][i])
        action = ACTIONS.get(executed, "-")
        colour = COLOURS["text"]
        if info["intervened"][i]:
            action, colour = f"{ACTIONS[proposed]} -> {ACTIONS[executed]} (supervisor)", COLOURS["intervened"]
        if info["crashed"][i]:
            action, colour = action + "   CRASH", COLOURS["crashed"]
        state = "left the road" if info["exited"][i] else f"{info['speed'][i]:5.1f} m/s"
        draw.text((8, 4 + LINE * (i + 1)), f"AV {i}: {state}   {action}", fill=colour)
    return np.concatenate([np.asarray(band), np.asarray(road)], axis=0)


def record_video(
    policy: Policy,
    env_id: str,
    path: str | Path,
    n_episodes: int = 1,
    seed: int = 0,
    config: dict[str, Any] | None = None,
    n_frames: int | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Play ``n_episodes`` seeded episodes (the density's AV counts from the largest down, cycling)
    and write them to the mp4 ``path``, one frame per policy step (5 Hz, played at 5 fps: real
    time), each drawn by :func:`frame`.

    :param n_frames: instead of ``n_episodes``, episodes until this many frames, the video cut there
        (rl-zoo's ``-n`` timesteps)
    :return: ``{"path", "frames", "episodes", "fps"}``
    """
    path, imageio = Path(path), imageio_module()
    counts = sorted(av_counts(env_id, config), reverse=True)
    frames: list[np.ndarray] = []
    fps, episode = None, 0
    unit = "frame" if n_frames else "episode"
    with tqdm(
        total=n_frames or n_episodes, desc="recording", unit=unit, leave=False, disable=None if progress else True
    ) as bar:
        while (len(frames) < n_frames) if n_frames else (episode < n_episodes):
            n_avs = counts[episode % len(counts)]
            env = make_scenario(env_id, {**(config or {}), **VIEW, "n_avs": n_avs}, render_mode="rgb_array")
            fps = env.config["policy_frequency"]
            before = len(frames)
            run_episodes(env, policy, 1, seed + episode, on_step=lambda env, info: frames.append(frame(env, info, counts[0])))
            env.close()
            bar.update(len(frames) - before if n_frames else 1)
            episode += 1
    frames = frames[:n_frames]
    # libx264 needs even frame sizes; macro_block_size=2 pads odd ones instead of rescaling
    with (
        replaced_atomically(path) as temporary,
        imageio.get_writer(temporary, fps=fps, codec="libx264", macro_block_size=2, format="FFMPEG") as writer,
    ):
        for picture in frames:
            writer.append_data(picture)
    return {"path": str(path), "frames": len(frames), "episodes": episode, "fps": fps}


__all__ = ["VideoExtraMissing", "frame", "imageio_module", "record_video"]
