"""Shared test configuration: headless plotting and a small default torch thread count."""

import os

os.environ.setdefault("MPLBACKEND", "Agg")

import torch

torch.set_num_threads(1)
