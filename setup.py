"""sb3-marl: multi-agent RL for cooperative lane changing of connected AVs, on Stable-Baselines3."""

from pathlib import Path

from setuptools import find_packages, setup

RAY = ["ray[tune]>=2.60,<2.61"]
PETTINGZOO = ["pettingzoo>=1.27,<1.28", "supersuit>=3.10,<3.11"]
# other MARL libraries on the PettingZoo env (README "Other MARL libraries")
TORCHRL = ["torchrl>=0.14,<0.15", *PETTINGZOO]
RLLIB = ["ray[rllib]>=2.60,<2.61", *PETTINGZOO]  # RLlib pins gymnasium 1.2.x
# BenchMARL 1.5 pins torchrl < 0.12 (and torchvision): its own environment, not [dev]
BENCHMARL = ["benchmarl>=1.5,<1.6", *PETTINGZOO]
# videos (`record-video`, the Hub's replay.mp4): imageio-ffmpeg's wheel carries ffmpeg (165 MB)
VIDEO = ["imageio>=2.34", "imageio-ffmpeg>=0.5"]
# the documentation site (mkdocs.yml): MkDocs Material, the API reference from the docstrings
DOCS = ["mkdocs>=1.6,<2", "mkdocs-material>=9.5,<10", "mkdocstrings[python]>=1.0,<2"]

setup(
    name="sb3-marl",
    version="0.1.0",
    description="Stable-Baselines3 extension for multi-agent RL of cooperative AV lane changes in mixed traffic",
    long_description=Path("README.md").read_text(encoding="utf-8"),
    long_description_content_type="text/markdown",
    author="sb3-marl developers",
    license="MIT",
    keywords="reinforcement-learning multi-agent autonomous-vehicles highway-env stable-baselines3 pettingzoo",
    python_requires=">=3.10",
    # zoo_configs/ ships beside the packages, so sb3_marl finds it installed as in a checkout
    packages=[*find_packages(include=["sb3_marl", "sb3_marl.*", "wrappers", "wrappers.*"]), "zoo_configs"],
    # the console script's entry point: takes signals before the package imports (its doc)
    py_modules=["sb3_marl_launcher"],
    package_data={"zoo_configs": ["*.yml", "grids/*.yml"]},
    install_requires=[
        # any torch 2 release; the README installs the CPU build first (`pip install torch==2.13.0`)
        "torch>=2.3,<3",
        "stable-baselines3>=2.9,<2.10",
        "sb3-contrib>=2.9,<2.10",
        "highway-env>=1.12,<1.13",
        "gymnasium>=1.0,<2",
        "numpy>=1.26",
        "numba>=0.68,<0.69",  # the safety supervisor's compiled prediction
        "tensorboard>=2.15",
        "pyyaml>=6",
        "rl_zoo3>=2.9,<2.10",
        "matplotlib>=3.8",
        "tqdm",
        "rich",
        "huggingface_hub>=1.0",  # push-to-hub / load-from-hub
        "requests",  # rl_zoo3's plotting scripts, which read our log folders
        "filelock>=3",  # one launcher per benchmark grid folder
    ],
    extras_require={
        # Ray Tune runs the paper-reproduction benchmark (`sb3-marl benchmark`)
        "ray": RAY,
        # the scenario as a PettingZoo ParallelEnv (sb3_marl.envs.parallel_env), SuperSuit to feed it to SB3
        "pettingzoo": PETTINGZOO,
        "torchrl": TORCHRL,
        "rllib": RLLIB,
        "benchmarl": BENCHMARL,
        "video": VIDEO,
        "docs": DOCS,
        # seaborn and scipy: rl_zoo3's own plotting scripts, run by the tests on our logs;
        # ruff and mypy: lint and types, run by `make test`
        # build: the packaging test builds the sdist; docs: the strict docs build
        # moto (S3), flask, flask-cors: the S3 server of the two-node grid test (tests/benchmark/test_cluster.py)
        "dev": [
            "pytest>=8",
            "moto[s3]>=5,<6",
            "flask",
            "flask-cors",
            "hypothesis>=6.100",
            "seaborn",
            "scipy",
            "ruff>=0.16,<0.17",
            "mypy>=2.3,<2.5",
            "build",
            *VIDEO,
            *RAY,
            *TORCHRL,
            *RLLIB,
            *DOCS,
        ],
    },
    entry_points={"console_scripts": ["sb3-marl=sb3_marl_launcher:main"]},
    classifiers=[
        "Development Status :: 4 - Beta",
        "Intended Audience :: Science/Research",
        "Operating System :: OS Independent",
        "Programming Language :: Python :: 3",
        "Programming Language :: Python :: 3.10",
        "Programming Language :: Python :: 3.11",
        "Programming Language :: Python :: 3.12",
        "Topic :: Scientific/Engineering :: Artificial Intelligence",
    ],
)
