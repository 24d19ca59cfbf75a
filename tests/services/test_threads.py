"""The services run their arithmetic on one torch thread and one BLAS thread (as the in-process runner)."""
import json
import subprocess
import sys


def test_apply_torch_threads_limits_torch_and_blas():
    code = ("import json, numpy, torch\n"
            "from threadpoolctl import threadpool_info\n"
            "from services.common.runtime import apply_torch_threads\n"
            "apply_torch_threads()\n"
            "blas = [p['num_threads'] for p in threadpool_info() if p['user_api'] == 'blas']\n"
            "print(json.dumps({'torch': torch.get_num_threads(), 'blas': blas}))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env={"OPENBLAS_NUM_THREADS": "2", "PATH": "/usr/bin:/bin"}, check=True)
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got["torch"] == 1 and got["blas"] and all(n == 1 for n in got["blas"])
