"""Paper-reproduction benchmark: the experiment grid of Zhou, Chen et al. as Ray Tune trials
(:mod:`~sb3_marl.benchmark.runner`), aggregated into the paper's table and figures
(:mod:`~sb3_marl.benchmark.report`). Ray is an optional dependency (``pip install sb3-marl[ray]``)
imported only when trials run."""

from sb3_marl.benchmark.grid import EXPERIMENTS, GRIDS, VARIANTS, TrialSpec, make_grid

__all__ = ["EXPERIMENTS", "GRIDS", "VARIANTS", "TrialSpec", "make_grid"]
