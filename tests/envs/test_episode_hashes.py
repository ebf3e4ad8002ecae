"""The same seeds give the same episodes as the recorded code (tests/envs/episode_hashes.json,
recorded before the packages became layers; the lane change's supervisor-on episodes recorded again
when its default became version 5, its version-3 episodes kept as they were): every scenario id,
supervisor on and off."""

import json
from pathlib import Path

from episode_hashes import all_hashes


def test_seeded_episodes_are_the_recorded_ones():
    recorded = json.loads(Path(__file__).with_name("episode_hashes.json").read_text())
    assert all_hashes() == recorded
