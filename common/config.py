"""Documented config dataclasses that are also the command line.

Each field's `help` metadata is its documentation and its --help text; parsing happens only at the edge
(`parse_config`), validation in the dataclass's `__post_init__` (a ValueError naming the field), and the
resulting object is written as the first record of every log (`config_record`).

Configs nest: a field whose type is a config dataclass becomes a group of dotted flags
(`--agent.lr 5e-4`, `--observer.p-feedback 0.2`) and a nested object in `--config FILE` (JSON or YAML)
and in the record. `flatten=True` keeps a group's flags unprefixed (the task's `--env`, `--seed`);
`exclude=(...)` leaves some of the group's fields off the command line (the parent sets them). The parent builds
the nested object from the values given (a dict: see `nested`) in its `__post_init__`, so it can start
from a preset (the agent's algorithm). Errors (an unknown flag or setting, a bad value) are one line
naming the offender.
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
    """A documented dataclass field; `choices=`, `positional=True`, `cli=False`, `flatten=True` and
    `exclude=(names)` (nested configs) are honoured by the CLI."""
    if isinstance(default, (list, dict, set)) or dataclasses.is_dataclass(default):
        return dataclasses.field(default_factory=lambda: default, metadata={"help": help, **extra})
    return dataclasses.field(default=default, metadata={"help": help, **extra})


def nested(value: Any, cls: type[T], build=None, name: str = "") -> T:
    """For a parent's `__post_init__`: `value` as a `cls` (a dict of settings, None for the defaults, or
    already a `cls`); `build(**settings)` makes it (default `cls`). A bad or unknown setting is a
    ValueError prefixed with `name` (the parent's field)."""
    if isinstance(value, cls):
        return value
    settings = dict(value or {})
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(settings) - names)
    prefix = f"{name}: " if name else ""
    if unknown:
        raise ValueError(f"{prefix}unknown setting {unknown[0]!r}")
    try:
        return (build or cls)(**settings)
    except ValueError as exc:
        raise ValueError(f"{prefix}{exc}") from None


def _unwrap_optional(tp) -> tuple[Any, bool]:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return args[0], True
    return tp, False


def _config_type(tp) -> type | None:
    base, _ = _unwrap_optional(tp)
    return base if isinstance(base, type) and dataclasses.is_dataclass(base) else None


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
                raise argparse.ArgumentTypeError(
                    f"--{name} expects comma-separated {item.__name__}s, got {text!r}") from None
        if base is bool:
            if text.lower() in ("1", "true", "yes", "on"):
                return True
            if text.lower() in ("0", "false", "no", "off"):
                return False
            raise argparse.ArgumentTypeError(f"--{name} expects true/false, got {text!r}")
        try:
            return base(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"--{name} expects {base.__name__}, got {text!r}") from None

    convert.__name__ = getattr(base, "__name__", "value")
    return convert


def _leaves(cls: type, flag_prefix: str = "", path: tuple[str, ...] = (), exclude=()):
    """(path of field names, flag, field, type hint) of every command-line setting of `cls`, nested ones
    included (depth first)."""
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if not f.init or f.metadata.get("cli") is False or f.name in exclude:
            continue
        sub = _config_type(hints[f.name])
        if sub is not None:
            prefix = flag_prefix if f.metadata.get("flatten") else f"{flag_prefix}{f.name.replace('_', '-')}."
            yield from _leaves(sub, prefix, path + (f.name,), f.metadata.get("exclude", ()))
        else:
            yield path + (f.name,), flag_prefix + f.name.replace("_", "-"), f, hints[f.name]


def _default(f: dataclasses.Field) -> Any:
    return f.default if f.default is not dataclasses.MISSING else f.default_factory()


def add_config_arguments(parser: argparse.ArgumentParser, cls: type) -> None:
    for path, flag, f, hint in _leaves(cls):
        default = _default(f)
        shown = ",".join(str(x) for x in default) if isinstance(default, tuple) else default
        kwargs = dict(type=_converter(hint, flag), default=dataclasses.MISSING,
                      help=f"{f.metadata.get('help', '')} (default: {shown})")
        if "choices" in f.metadata:
            kwargs["choices"] = f.metadata["choices"]
            kwargs.pop("type")
        if f.metadata.get("positional"):
            parser.add_argument(f.name, metavar=flag.upper(), **kwargs)
        else:
            parser.add_argument(f"--{flag}", dest="/".join(path), **kwargs)
    parser.add_argument("--config", dest="_config_file", default=None, metavar="FILE",
                        help="JSON or YAML file of settings (nested as the log's config record); flags given on "
                             "the command line override it")


def _load_file(path: str) -> dict:
    with open(path) as fh:
        if path.endswith((".yaml", ".yml")):
            import yaml

            loaded = yaml.safe_load(fh)
        else:
            loaded = json.load(fh)
    if not isinstance(loaded, dict):
        raise ValueError(f"{path}: expected an object of settings")
    return loaded


def _check_file(cls: type, data: dict, where: str) -> dict:
    """`data` with lists made tuples; an unknown setting (at any depth) is a ValueError naming it."""
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    data = dict(data)
    for f in fields.values():  # a flattened group's settings may also be given at this level (env: ...)
        sub = _config_type(hints[f.name])
        if f.metadata.get("flatten") and sub is not None:
            for name in [k for k in data if k not in fields and k in {g.name for g in dataclasses.fields(sub)}]:
                group = data.setdefault(f.name, {})
                group[name] = data.pop(name)
    out = {}
    for key, value in data.items():
        if key not in fields:
            raise ValueError(f"{where}: unknown setting {key!r}")
        sub = _config_type(hints[key])
        if sub is not None and isinstance(value, dict):
            value = _check_file(sub, value, f"{where}: {key}")
        elif isinstance(value, list):
            value = tuple(value)
        out[key] = value
    return out


def _set(tree: dict, path: tuple[str, ...], value: Any) -> None:
    for name in path[:-1]:
        node = tree.get(name)
        if not isinstance(node, dict):
            node = tree[name] = {} if node is None else dataclasses.asdict(node)
        tree = node
    tree[path[-1]] = value


def config_from_namespace(cls: type[T], ns: argparse.Namespace) -> T:
    values: dict[str, Any] = {}
    config_file = getattr(ns, "_config_file", None)
    if config_file:
        loaded = _load_file(config_file)
        loaded.pop("type", None)  # written by config_record
        values = _check_file(cls, loaded, config_file)
    for path, _, _, _ in _leaves(cls):
        v = getattr(ns, "/".join(path), dataclasses.MISSING)
        if v is not dataclasses.MISSING:
            _set(values, path, v)
    return cls(**values)


class ConfigParser(argparse.ArgumentParser):
    """argparse whose errors are one line (`prog: error: ...`), without the usage block."""

    def error(self, message: str):
        if message.startswith("unrecognized arguments: "):
            flags = [t for t in message.split(": ", 1)[1].split() if t.startswith("-")]
            message = "unknown setting " + (" ".join(flags) or message.split(": ", 1)[1])
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def parse_config(cls: type[T], argv: list[str] | None = None, prog: str | None = None,
                 description: str | None = None) -> T:
    """Build `cls` from the command line; a bad value exits with a one-line error naming it."""
    parser = ConfigParser(prog=prog, description=description or (cls.__doc__ or "").strip())
    add_config_arguments(parser, cls)
    ns = parser.parse_args(argv)
    try:
        return config_from_namespace(cls, ns)
    except (ValueError, OSError) as exc:
        parser.error(str(exc))
        raise  # unreachable


def config_record(config: Any) -> dict:
    """The config as a JSON-able dict (tuples become lists, nested configs nested dicts), with its type name."""
    data = dataclasses.asdict(config)
    return {"type": type(config).__name__, **json.loads(json.dumps(data))}


def fail(message: str, code: int = 2) -> None:
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(code)
