"""Documented config dataclasses that are also the command line.

Each field's `help` metadata is its documentation and its --help text; parsing happens only at the edge
(`parse_config`), validation in the dataclass's `__post_init__` (a ValueError naming the field), and the
resulting object is written as the first record of every log (`config_record`).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import types
import typing
from typing import Any, TypeVar

T = TypeVar("T")


def option(default: Any, help: str, **extra) -> Any:
    """A documented dataclass field; `choices=` and `positional=True` are honoured by the CLI."""
    if isinstance(default, (list, dict, set)):
        return dataclasses.field(default_factory=lambda: default, metadata={"help": help, **extra})
    return dataclasses.field(default=default, metadata={"help": help, **extra})


def _unwrap_optional(tp) -> tuple[Any, bool]:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return args[0], True
    return tp, False


def _converter(tp, name: str):
    base, optional = _unwrap_optional(tp)
    origin = typing.get_origin(base)

    def convert(text: str):
        if optional and text.lower() in ("none", ""):
            return None
        if origin is tuple:
            item = typing.get_args(base)[0]
            try:
                return tuple(item(x) for x in text.split(",") if x.strip())
            except ValueError:
                raise argparse.ArgumentTypeError(f"--{name} expects comma-separated {item.__name__}s, got {text!r}")
        if base is bool:
            if text.lower() in ("1", "true", "yes", "on"):
                return True
            if text.lower() in ("0", "false", "no", "off"):
                return False
            raise argparse.ArgumentTypeError(f"--{name} expects true/false, got {text!r}")
        try:
            return base(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"--{name} expects {base.__name__}, got {text!r}")

    convert.__name__ = getattr(base, "__name__", "value")
    return convert


def add_config_arguments(parser: argparse.ArgumentParser, cls: type) -> None:
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if not f.init or f.metadata.get("cli") is False:
            continue
        flag = f.name.replace("_", "-")
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        shown = ",".join(str(x) for x in default) if isinstance(default, tuple) else default
        kwargs = dict(type=_converter(hints[f.name], flag), default=dataclasses.MISSING,
                      help=f"{f.metadata.get('help', '')} (default: {shown})")
        if "choices" in f.metadata:
            kwargs["choices"] = f.metadata["choices"]
            kwargs.pop("type")
        if f.metadata.get("positional"):
            parser.add_argument(f.name, metavar=flag.upper(), **kwargs)
        else:
            parser.add_argument(f"--{flag}", dest=f.name, **kwargs)
    parser.add_argument("--config", dest="_config_file", default=None, metavar="FILE",
                        help="JSON file of settings; flags given on the command line override it")


def config_from_namespace(cls: type[T], ns: argparse.Namespace) -> T:
    values: dict[str, Any] = {}
    config_file = getattr(ns, "_config_file", None)
    if config_file:
        with open(config_file) as fh:
            loaded = json.load(fh)
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(loaded) - names)
        if unknown:
            raise ValueError(f"{config_file}: unknown settings {', '.join(unknown)}")
        values.update({k: tuple(v) if isinstance(v, list) else v for k, v in loaded.items()})
    for f in dataclasses.fields(cls):
        v = getattr(ns, f.name, dataclasses.MISSING)
        if v is not dataclasses.MISSING:
            values[f.name] = v
    return cls(**values)


def parse_config(cls: type[T], argv: list[str] | None = None, prog: str | None = None,
                 description: str | None = None) -> T:
    """Build `cls` from the command line; a bad value exits with a one-line error naming it."""
    parser = argparse.ArgumentParser(prog=prog, description=description or (cls.__doc__ or "").strip())
    add_config_arguments(parser, cls)
    ns = parser.parse_args(argv)
    try:
        return config_from_namespace(cls, ns)
    except (ValueError, OSError) as exc:
        parser.error(str(exc))
        raise  # unreachable


def config_record(config: Any) -> dict:
    """The config as a JSON-able dict (tuples become lists), with its type name."""
    data = dataclasses.asdict(config)
    return {"type": type(config).__name__, **json.loads(json.dumps(data))}


def fail(message: str, code: int = 2) -> None:
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(code)
