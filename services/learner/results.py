"""What the learner's core says of each input: a feedback's outcome (`FeedbackResult`) and a finished episode
(`EpisodeRecord`); and the weights the service last published (`PublishedWeights`)."""

from __future__ import annotations

import dataclasses

from common.protocol import Feedback


@dataclasses.dataclass
class FeedbackResult:
    teacher: str
    seq: int
    status: str  # credited | stale | too_old | ignored | after_end | actor_restarted
    steps: int = 0
    lost_mass: float = 0.0
    received_at: int = 0  # position of the feedback in the ingest record (for latency bookkeeping)
    revision: int | None = None  # the weights revision right after its H update (None: it updated nothing)
    feedback: Feedback | None = None  # the feedback itself, once resolved by credit (Credit messages)
    credited: list = dataclasses.field(default_factory=list)  # [(Step.seq, weight)] when credited


@dataclasses.dataclass
class EpisodeRecord:
    incarnation: str
    episode: int
    return_: float
    steps: int
    feedback_received: int
    feedback_credited: int
    weights_version: int
    t_end: float


@dataclasses.dataclass(frozen=True)
class PublishedWeights:
    """The weights last published: the step count they are at (their version), the revision, the message sent."""

    version: int
    revision: int
    data: bytes | None = None
