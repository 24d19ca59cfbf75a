"""The algorithm core: credit, delay, the step loop, the simulated observer, the task (never imports zenoh)."""
