"""Sweeps: a grid of config fields run as batched, cached trials (local processes or Ray), one tidy table,
per-cell summaries, a figure per group of cells and named contrasts. See docs/sweeps.md."""
