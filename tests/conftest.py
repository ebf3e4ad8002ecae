"""Shared fixtures: headless rendering and one thread per process for reproducible timings."""

import os

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("OMP_NUM_THREADS", "1")
