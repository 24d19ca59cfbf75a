"""The field kinds the messages share: names that become a key's chunk, tokens, seconds, counts."""

from __future__ import annotations

from ._spec import Float, Int, Str

#: Names that become one chunk of a key expression (run, teacher_id, service, camera id): letters, digits,
#: `_ . : -`, starting with a letter or digit, at most 64 characters. This excludes every character that
#: Zenoh gives a meaning (`* $ / # ?`) and whitespace.
NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.:-]{0,63}$"
#: Free-form identifiers that never become part of a key (incarnation): printable ASCII, no spaces.
TOKEN_PATTERN = r"^[!-~]{1,128}$"


def Name(description: str) -> Str:
    return Str(64, pattern=NAME_PATTERN, min_len=1, description=description)


def Token(description: str) -> Str:
    return Str(128, pattern=TOKEN_PATTERN, min_len=1, description=description)


def Seconds(description: str) -> Float:
    return Float(0.0, description=description)


def Count(description: str) -> Int:
    return Int(0, description=description)


RUN = "Run name; also the second chunk of every key expression."
