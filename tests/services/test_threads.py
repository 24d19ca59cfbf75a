"""The services run their arithmetic on one torch thread and one BLAS thread (as the in-process runner), and
an actor or learner of the numpy MLP never imports torch (its import costs about 1.3 s of CPU at start)."""

import json
import subprocess
import sys

import pytest

THREADS = (
    "from threadpoolctl import threadpool_info\n"
    "blas = [p['num_threads'] for p in threadpool_info() if p['user_api'] == 'blas']\n"
    "print(json.dumps({'torch': torch.get_num_threads(), 'blas': blas}))\n"
)


def _run(code: str) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=120,
        env={"OPENBLAS_NUM_THREADS": "2", "PATH": "/usr/bin:/bin"},
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("torch_first", [True, False], ids=["torch-loaded-before", "torch-loaded-after"])
def test_apply_torch_threads_limits_torch_and_blas(torch_first):
    load = "import torch\n"
    code = (
        "import json, numpy\n"
        + (load if torch_first else "")
        + "from services.common.runtime import apply_torch_threads\napply_torch_threads()\n"
        + ("" if torch_first else load)
        + THREADS
    )
    got = _run(code)
    assert got["torch"] == 1 and got["blas"] and all(n == 1 for n in got["blas"])


def test_the_numpy_mlp_agent_is_built_and_acts_without_torch():
    code = (
        "import json, sys, numpy as np\n"
        "from services.common.runtime import apply_torch_threads\napply_torch_threads()\n"
        "from common.agents import TrialBatchAgent, agent_config\n"
        "agent = TrialBatchAgent([agent_config('dqn-tamer')], 4, 3, [7])\n"
        "agent.policy_weights(0)\n"
        "print(json.dumps({'torch': 'torch' in sys.modules}))\n"
    )
    assert _run(code) == {"torch": False}
