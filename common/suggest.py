""" "Did you mean": the flag or setting a misspelt or renamed one most likely meant."""

from __future__ import annotations

import difflib


def suggest(name: str, known: list[str]) -> str:
    """ "; did you mean X?" for a flag or setting that was renamed or misspelt: the nested one with the same
    leaf name (`--p-feedback` -> `--observer.p-feedback`), else the closest spelling; "" when none is near."""

    def leaf(flag: str) -> str:
        return flag.lstrip("-").rsplit(".", 1)[-1].replace("_", "-")

    same_leaf = [k for k in known if leaf(k) == leaf(name) and k != name]
    close_leaf = difflib.get_close_matches(leaf(name), [leaf(k) for k in known], n=1, cutoff=0.8)
    close = (
        same_leaf
        or difflib.get_close_matches(name, known, n=1, cutoff=0.75)
        or [k for k in known if close_leaf and leaf(k) == close_leaf[0]]
    )
    return f"; did you mean {' or '.join(close[:3])}?" if close else ""
