"""docs/protocol.md is generated from the code and must stay equal to it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from common.protocol import KEYS
from common.protocol._docs import markdown

ROOT = Path(__file__).resolve().parents[2]
DOC = ROOT / "docs" / "protocol.md"
REGENERATE = "python -m services protocol --markdown > docs/protocol.md"


def test_committed_protocol_doc_equals_generated():
    assert DOC.read_text(encoding="utf-8") == markdown(), f"docs/protocol.md is stale: run `{REGENERATE}`"


def test_cli_prints_the_same_markdown():
    out = subprocess.run(
        [sys.executable, "-m", "services", "protocol", "--markdown"],
        cwd=ROOT,
        capture_output=True,
        check=True,
        timeout=60,
    ).stdout.decode("utf-8")
    assert out == markdown()


def test_doc_names_every_key_and_type():
    text = markdown()
    for spec in KEYS.values():
        assert f"`{spec.pattern()}`" in text
        assert f"### {spec.message.__name__}" in text
