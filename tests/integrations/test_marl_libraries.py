"""Other MARL libraries on the PettingZoo env, as their users run them: the docs' TorchRL,
RLlib and BenchMARL examples verbatim, TorchRL's spec check at densities 1 and 3, and masked
actions never taken (TorchRL's masked rollout; RLlib's action-masking module on a recording env)."""

import importlib.util
import re
import subprocess
import sys
import types

import numpy as np
import pytest
from documents import code as docs_code

from sb3_marl.envs import parallel_env
from sb3_marl.envs.parallel import ScenarioParallelEnv


def readme_example(library: str) -> str:
    """The example of ``library`` on the docs page of other MARL libraries."""
    return docs_code("marl-libraries.md", library)


def test_the_dev_environment_is_coherent():
    result = subprocess.run([sys.executable, "-m", "pip", "check"], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.parametrize("density", [1, 3])
def test_the_torchrl_example_passes_check_env_specs_and_never_takes_a_masked_action(density, capsys):
    code = readme_example("TorchRL")
    if density != 3:
        code = code.replace("density=3", f"density={density}").replace("6 AVs", f"{density + 2} AVs")
    exec(compile(code, "marl-libraries.md", "exec"), {})
    out = capsys.readouterr().out
    assert "masked actions taken: 0" in out
    n_avs = {1: 3, 3: 6}[density]
    assert f"global state: (50, {n_avs * 25})" in out


class RecordingEnv(ScenarioParallelEnv):
    """The real env, counting the actions it receives that the scenario's current action masks exclude."""

    masked_taken: list = []
    actions_seen = 0

    @classmethod
    def reset_counts(cls) -> None:
        cls.masked_taken, cls.actions_seen = [], 0

    def step(self, actions):
        masks = self.env.action_masks()
        for agent, action in actions.items():
            RecordingEnv.actions_seen += 1
            i = self.possible_agents.index(agent)
            if not masks[i, action]:
                RecordingEnv.masked_taken.append((self.env.steps, agent, int(action), masks[i].astype(int).tolist()))
        return super().step(actions)


@pytest.fixture
def ray_shut_down_after():
    """RLlib starts a local Ray instance; the tests after these must not inherit it."""
    yield
    import ray

    ray.shutdown()


def test_the_rllib_example_trains_two_iterations_of_shared_masked_ppo(capsys, ray_shut_down_after):
    exec(compile(readme_example("RLlib"), "marl-libraries.md", "exec"), {})
    lines = [line.split() for line in capsys.readouterr().out.splitlines() if re.fullmatch(r"[01] \d+(\.\d+)?", line)]
    assert [line[0] for line in lines] == ["0", "1"] and float(lines[1][1]) > float(lines[0][1]) > 0


def test_rllib_with_the_action_masking_module_never_takes_a_masked_action(ray_shut_down_after):
    code = re.sub(r"ParallelPettingZooEnv\(\s*parallel_env\(", "ParallelPettingZooEnv(RecordingEnv(", readme_example("RLlib"))
    assert "ParallelPettingZooEnv(RecordingEnv(" in code
    # RLlib's env check at build time steps the env with unmasked random actions: count from training on
    code = code.replace("algo = config.build_algo()\n", "algo = config.build_algo()\nRecordingEnv.reset_counts()\n")
    assert "RecordingEnv.reset_counts()" in code
    exec(compile(code, "marl-libraries.md", "exec"), {"RecordingEnv": RecordingEnv})
    assert RecordingEnv.actions_seen >= 400 and RecordingEnv.masked_taken == []


def test_masks_are_real_constraints_on_this_env():
    """Without masking some actions are unavailable: the checks above can fail."""
    env = parallel_env(density=1, action_mask_in_observation=True)
    observations, _ = env.reset(seed=0)
    assert any(not obs["action_mask"].all() for obs in observations.values())
    assert np.all([obs["action_mask"].dtype == np.int8 for obs in observations.values()])


@pytest.mark.skipif(
    importlib.util.find_spec("benchmarl") is None,
    reason="BenchMARL is not installed: it pins TorchRL < 0.12, which cannot live beside the "
    "[dev] extra's TorchRL 0.14; install the [benchmarl] extra in its own environment",
)
def test_the_benchmarl_example_runs_two_iterations_of_mappo(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    module = types.ModuleType("benchmarl_readme_example")  # BenchMARL pickles the task class: a real module
    monkeypatch.setitem(sys.modules, module.__name__, module)
    exec(compile(readme_example("BenchMARL"), "marl-libraries.md", "exec"), module.__dict__)
    assert "BenchMARL MAPPO: 2 iterations" in capsys.readouterr().out
