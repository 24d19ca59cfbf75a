"""The logs: MCAP writing and reading (crash and damage recovery), the scene drawn for Foxglove, learning curves."""
