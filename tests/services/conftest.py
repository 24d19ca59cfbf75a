"""Shared fixtures of the service tests: one torch thread (as the services use), and process hygiene."""

from __future__ import annotations

import torch

torch.set_num_threads(1)
