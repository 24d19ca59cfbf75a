"""Child process for the SIGKILL test: writes a Step every 5 ms and prints each seq after writing it."""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from common.logs.mcap_log import LogWriter  # noqa: E402
from common.protocol import RunConfig, Step, step_key  # noqa: E402

path = sys.argv[1]
writer = LogWriter(path, RunConfig.create("killed", {"note": "sigkill test"}))
try:
    seq = 0
    while True:
        step = Step(
            run="killed",
            incarnation="w",
            seq=seq,
            t_action=time.time(),
            episode=0,
            t_in_episode=seq,
            obs=[0.0],
            action=0,
            reward=0.0,
            next_obs=[1.0],
            terminated=False,
            truncated=False,
            weights_version=0,
            info={},
        )
        writer.write(step_key("killed"), step.encode())
        print(seq, time.time(), flush=True)
        seq += 1
        time.sleep(0.005)
finally:
    writer.finish()
