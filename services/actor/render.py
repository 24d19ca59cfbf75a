"""The environment's own picture, for environments the console has no scene for (`common/envs/scene.py`):
after each step the actor renders the env as RGB and publishes it as a JPEG `foxglove.CompressedImage` on
`hitl/<run>/camera/env` (frame_id = the Step.seq it shows), so a person sees what the agent does."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from common.protocol import CompressedImage, Time, camera_key

CAMERA = "env"
MAX_SIDE = 320  # px: a picture for a person, not a dataset


def enable_rgb(env: Any) -> bool:
    """Switch a Gymnasium env (and its wrappers' inner env) to rgb_array rendering. False if it has none."""
    inner = getattr(env, "unwrapped", env)
    if "rgb_array" not in (getattr(inner, "metadata", {}) or {}).get("render_modes", ()):
        return False
    inner.render_mode = "rgb_array"
    return True


class FramePublisher:
    def __init__(self, session: Any, run: str, env: Any, counters):
        from common.wire.transport import MessagePublisher

        self.env, self.counters = getattr(env, "unwrapped", env), counters
        self.pub = MessagePublisher(session, camera_key(run, CAMERA))

    def publish(self, seq: int) -> None:
        import cv2

        try:
            rgb: np.ndarray = np.asarray(self.env.render(), np.uint8)
            scale = MAX_SIDE / max(rgb.shape[:2])
            if scale < 1:
                rgb = cv2.resize(
                    rgb, (int(rgb.shape[1] * scale), int(rgb.shape[0] * scale)), interpolation=cv2.INTER_AREA
                )
            ok, jpeg = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 80])
        except Exception:  # a picture must never stop the actor
            self.counters["render_failed"] += 1
            return
        if ok:
            self.pub.put(
                CompressedImage(
                    timestamp=Time.from_seconds(time.time()), frame_id=str(seq), data=jpeg.tobytes(), format="jpeg"
                )
            )
            self.counters["frames_rendered"] += 1

    def close(self) -> None:
        self.pub.close()
