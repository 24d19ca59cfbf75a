"""Messages for logs and viewers: weights in a form a viewer can plot, and a request for the weights now."""

from __future__ import annotations

import dataclasses
from typing import ClassVar

from ._base import List, Message, Nullable, Obj, fld
from ._fields import RUN, Count, Name, Seconds, Token
from ._spec import Bytes64, Float, Int, Str

SNAPSHOT_REASONS = ("start", "every", "episode", "request", "final")


@dataclasses.dataclass(frozen=True)
class TensorSummary:
    name: str
    shape: list
    mean: float
    std: float
    min: float
    max: float
    norm: float


TENSOR_SUMMARY_SPEC = Obj(
    {
        "name": Str(128, description="Tensor name, e.g. `q.0.weight`."),
        "shape": List(Int(0, 2**31 - 1), max_items=8, description="Shape."),
        "mean": Float(description="Mean of the entries."),
        "std": Float(0.0, description="Standard deviation of the entries."),
        "min": Float(description="Smallest entry."),
        "max": Float(description="Largest entry."),
        "norm": Float(0.0, description="L2 norm."),
    },
    cls=TensorSummary,
    description="Summary numbers of one tensor.",
)


@dataclasses.dataclass(frozen=True)
class WeightsSnapshot(Message):
    """The learner's weights for viewers and logs (published on `hitl/<run>/snapshot` at a bounded rate: every
    `snapshot_every` steps learned, at each episode end, on request and at the end): summary numbers per
    tensor, which a plot can follow, and (except at episode ends) the raw weights as the bytes of a Weights
    message, which `Weights.decode` reads back."""

    TYPE_NAME: ClassVar[str] = "hitl.WeightsSnapshot"
    MAX_BYTES: ClassVar[int] = 48 * 1024 * 1024

    run: str = fld(Name(RUN))
    incarnation: str = fld(Token("The learner process's incarnation."))
    version: int = fld(Count("The weights version (steps learned; steps learned + 1 for the final weights)."))
    reason: str = fld(
        Str(
            enum=SNAPSHOT_REASONS,
            description=(
                "Why now: `start`, `every` (N steps learned), `episode` (an episode ended), `request`, `final`."
            ),
        )
    )
    t_published: float = fld(Seconds("Wall-clock time (s) of publication."))
    tensors: list = fld(List(TENSOR_SUMMARY_SPEC, max_items=64, description="One summary per tensor."))
    weights: bytes | None = fld(
        Nullable(
            Bytes64(
                32 * 1024 * 1024,
                description=(
                    "The raw weights: the bytes of a `hitl.Weights` message (safetensors); null at episode ends."
                ),
            )
        )
    )


@dataclasses.dataclass(frozen=True)
class Request(Message):
    """Ask a service for something now (published on `hitl/<run>/request`): `snapshot` makes the learner
    publish a WeightsSnapshot with the raw weights (at most a few per second)."""

    TYPE_NAME: ClassVar[str] = "hitl.Request"
    MAX_BYTES: ClassVar[int] = 1024

    run: str = fld(Name(RUN))
    what: str = fld(Str(enum=("snapshot",), description="What is asked for."))
    by: str = fld(Name("Who asks (a service or a person's tool)."))
    t: float = fld(Seconds("Wall-clock time (s) of the request."))


__all__ = ["WeightsSnapshot", "TensorSummary", "Request", "SNAPSHOT_REASONS"]
