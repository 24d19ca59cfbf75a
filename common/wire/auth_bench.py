"""`python -m services auth-bench`: what signing and checking a message costs, per message size."""

from __future__ import annotations

import dataclasses
import os
import secrets
import time
from typing import Any

from common.config import option


from common.wire.auth import Auth, service_credential


def bench(n: int = 20000, repeats: int = 7) -> list[dict[str, Any]]:
    """Microseconds per message to sign (publisher) and to check (each receiver), for a Step, a Feedback and the
    DQN-TAMER maze Weights, as the services send them (`python -m services auth-bench`)."""
    import numpy as np

    from common.protocol import Feedback, Step, Weights, feedback_key, step_key, weights_key

    run = "bench"
    secret = secrets.token_bytes(32)
    step = Step(
        run=run,
        incarnation="actor-1-abcdef01",
        seq=12345,
        t_action=time.time(),
        episode=3,
        t_in_episode=17,
        obs=[0.0] * 8,
        action=2,
        reward=-0.01,
        next_obs=[1.0] * 8,
        terminated=False,
        truncated=False,
        weights_version=12345,
        info={"target_distance_before": 3.0, "target_distance_after": 2.0},
    )
    fb = Feedback(run=run, teacher_id="oracle", seq=321, t_reaction=time.time(), value=1, source="oracle")
    rng = np.random.default_rng(0)
    shapes = {"q.0.weight": (100, 8), "q.0.bias": (100,), "q.2.weight": (4, 100), "q.2.bias": (4,)}
    tensors = {f"{net}{k[1:]}": rng.standard_normal(s).astype(np.float32) for net in "qh" for k, s in shapes.items()}
    w = Weights(run=run, incarnation="learner-1-abcdef01", version=12345, t_published=time.time(), tensors=tensors)
    out = []
    for name, key, payload, sender, count in (
        ("Step", step_key(run), step.encode(), "actor", n),
        ("Feedback", feedback_key(run, "oracle"), fb.encode(), "teacher.oracle", n),
        ("Weights", weights_key(run), w.encode(), "learner", max(1, n // 20)),
    ):
        sign_s, check_s, bad = [], [], 0
        for _ in range(repeats):  # the best of several rounds: other processes only ever add time
            signer = Auth(service_credential(secret, run, sender))
            checker = Auth(service_credential(secret, run, "recorder"))
            t0 = time.perf_counter()
            tags = [signer.sign(key, payload) for _ in range(count)]
            t1 = time.perf_counter()
            bad += sum(checker.check(key, payload, tag) is not None for tag in tags)
            t2 = time.perf_counter()
            sign_s.append(t1 - t0)
            check_s.append(t2 - t1)
        out.append(
            {
                "message": name,
                "bytes": len(payload),
                "n": count,
                "repeats": repeats,
                "sign_us": min(sign_s) / count * 1e6,
                "check_us": min(check_s) / count * 1e6,
                "sign_us_median": sorted(sign_s)[len(sign_s) // 2] / count * 1e6,
                "check_us_median": sorted(check_s)[len(check_s) // 2] / count * 1e6,
                "rejected": bad,
            }
        )
    return out


@dataclasses.dataclass(frozen=True)
class AuthBenchConfig:
    """Microseconds per message to sign and to check (every message of a run is authenticated)."""

    n: int = option(20000, "messages per type and round (Weights: n/20)")
    repeats: int = option(7, "rounds; the best and the median are printed")


def bench_main(args: AuthBenchConfig) -> int:
    rows = bench(args.n, args.repeats)
    print(
        f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs; µs per message, best (median) of "
        f"{args.repeats} rounds"
    )
    print(f"{'message':<10}{'bytes':>8}{'sign µs':>18}{'check µs':>18}")
    for r in rows:
        print(
            f"{r['message']:<10}{r['bytes']:>8}{r['sign_us']:>9.2f} ({r['sign_us_median']:>5.1f})"
            f"{r['check_us']:>9.2f} ({r['check_us_median']:>5.1f})"
        )
    return 0 if all(r["rejected"] == 0 for r in rows) else 1


if __name__ == "__main__":
    from common.config import moved

    moved("python -m services auth-bench")
