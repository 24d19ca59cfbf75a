"""What the recorder accepts per sender and per second: a full disk must not be one flood away (issue 10).

Token buckets (capacity: one second's worth): every sender (the identity that publishes the key,
`common.protocol.sender_of`) at most `sender_bytes` bytes/s; every camera at most `camera_fps` frames/s and
`camera_bytes` bytes/s on top. What exceeds a cap is not written and is counted (`capped_<kind>`)."""

from __future__ import annotations

import time

from common.protocol import parse_key, sender_of

MAX_SENDERS = 256  # buckets kept (only authenticated senders reach the recorder; this bounds it anyway)


class Bucket:
    def __init__(self, rate: float, now: float):
        self.rate, self.level, self.t = float(rate), float(rate), now

    def take(self, amount: float, now: float) -> bool:
        self.level = min(self.rate, self.level + max(0.0, now - self.t) * self.rate)
        self.t = now
        if amount > self.level:
            return False
        self.level -= amount
        return True


class RecordCaps:
    def __init__(self, sender_bytes: float, camera_bytes: float, camera_fps: float):
        self.sender_bytes, self.camera_bytes, self.camera_fps = sender_bytes, camera_bytes, camera_fps
        self.buckets: dict[tuple[str, str], Bucket] = {}

    def _bucket(self, what: str, who: str, rate: float, now: float) -> Bucket:
        b = self.buckets.get((what, who))
        if b is None:
            if len(self.buckets) >= MAX_SENDERS:
                self.buckets.clear()
            b = self.buckets[(what, who)] = Bucket(rate, now)
        return b

    def admit(self, key: str, nbytes: int, now: float | None = None) -> bool:
        """True if a message of `nbytes` on `key` may be written now."""
        now = time.monotonic() if now is None else now
        parsed = parse_key(key)
        if parsed.spec.kind == "camera":
            if not (
                self._bucket("frames", key, self.camera_fps, now).take(1, now)
                and self._bucket("camera_bytes", key, self.camera_bytes, now).take(nbytes, now)
            ):
                return False
        return self._bucket("bytes", sender_of(key) or key, self.sender_bytes, now).take(nbytes, now)
