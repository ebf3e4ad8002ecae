"""The same seeds give the same episodes as the recorded code (tests/envs/episode_hashes.json;
tests/envs/episode_hashes.py says what is recorded and how): every scenario id, supervisor on and
off, and the lane change under supervisor versions 3 and 5. Discrete things (actions, masks, crashes,
lanes, lengths) must be equal; float things (observations, rewards, positions) within 1e-9 of
their size, so the record holds on any x86-64 machine, AVX2 or AVX-512."""

import json

from episode_hashes import RECORD, all_records, differences


def test_seeded_episodes_are_the_recorded_ones():
    recorded = json.loads(RECORD.read_text())
    assert differences(recorded, all_records()) == []
