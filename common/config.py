"""Documented config dataclasses that are also the command line.

Each field's `help` metadata is its documentation and its --help text; parsing happens only at the edge
(`parse_config`), validation in the dataclass's `__post_init__` (a ValueError naming the field), and the
resulting object is written as the first record of every log (`config_record`).

Configs nest: a field whose type is a config dataclass becomes a group of dotted flags
(`--agent.lr 5e-4`, `--observer.p-feedback 0.2`) and a nested object in `--config FILE` (JSON or YAML)
and in the record. `flatten=True` keeps a group's flags unprefixed (the task's `--env`, `--seed`);
`exclude=(...)` leaves some of the group's fields off the command line (the parent sets them); `was={name: "--old"}`
on a group (or `was=("--old",)` on a field) keeps a renamed flag working. A parent that subclasses `Groups`
reads its flattened groups' settings as its own (`up.rate` is `up.actor.rate`). The parent builds
the nested object from the values given (a dict: see `nested`) in its `__post_init__`, so it can start
from a preset (the agent's algorithm). Errors (an unknown flag or setting, a bad value) are one line
naming the offender.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import re
import sys
import types
import typing
from typing import Any, TypeVar
from common.suggest import suggest

T = TypeVar("T")


def option(default: Any, help: str, **extra) -> Any:
    """A documented dataclass field; `choices=`, `positional=True`, `nargs=` ("+", "*", "?": a tuple field
    given as several words, `--grid A B --grid C` adds up), `metavar=`, `flag=` (the flag's name where the
    field's cannot be it: `--from`), `was=("--old-flag",)` (a renamed flag that keeps working), `cli=False`,
    `flatten=True`, `exclude=(names)` and `was={name: "--old-flag"}` (nested configs) are honoured by the CLI.
    A bool flag given alone means true."""
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
    names = {f.name for f in dataclasses.fields(typing.cast(Any, cls))}
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
                    f"--{name} expects comma-separated {item.__name__}s, got {text!r}"
                ) from None
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
            yield path + (f.name,), flag_prefix + f.metadata.get("flag", f.name.replace("_", "-")), f, hints[f.name]


def _old_flags(cls: type, path: tuple[str, ...], f: dataclasses.Field) -> list[str]:
    """The renamed flags that still mean the setting at `path` (its own `was`, and its group's)."""
    old = [flag for flag in f.metadata.get("was", ()) if isinstance(flag, str)]
    for depth in range(len(path) - 1):
        group = {g.name: g for g in dataclasses.fields(cls)}[path[depth]]
        was = group.metadata.get("was", {})
        if isinstance(was, dict) and path[depth + 1] in was:
            old.append(was[path[depth + 1]])
        cls = _config_type(typing.get_type_hints(cls)[path[depth]]) or cls
    return old


def all_but(cls: type, *keep: str) -> tuple[str, ...]:
    """For `exclude=`: every field of `cls` but `keep` (a group of which the parent shows a few settings)."""
    return tuple(f.name for f in dataclasses.fields(cls) if f.name not in keep)


class Groups:
    """Mixin for a config with flattened groups: `cfg.rate` reads `cfg.actor.rate` when `rate` is no field of
    its own (the flags are unprefixed, so reading them unprefixed is the same spelling)."""

    def __getattr__(self, name: str) -> Any:
        if not name.startswith("_"):
            for f in dataclasses.fields(typing.cast(Any, self)):  # the subclass is a dataclass
                group = self.__dict__.get(f.name)
                if f.metadata.get("flatten") and dataclasses.is_dataclass(group) and hasattr(group, name):
                    return getattr(group, name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")


def _default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    return f.default_factory() if callable(f.default_factory) else None


def _default_at(cls: type, path: tuple[str, ...], f: dataclasses.Field) -> Any:
    """The default of the setting at `path`: a group whose default is a preset (`ActorSettings(episodes=15)`)
    says its own value, not the declaring class's."""
    node: Any = None
    for depth, name in enumerate(path[:-1]):
        node = _default({g.name: g for g in dataclasses.fields(cls)}[name]) if depth == 0 else getattr(node, name, None)
        if not dataclasses.is_dataclass(node):
            return _default(f)
    return getattr(node, path[-1]) if node is not None else _default(f)


def add_config_arguments(parser: argparse.ArgumentParser, cls: type) -> None:
    for path, flag, f, hint in _leaves(cls):
        default = _default_at(cls, path, f)
        shown = ",".join(str(x) for x in default) if isinstance(default, tuple) else default
        text = f.metadata.get("help", "")
        text = text if "default" in text else f"{text} (default: {shown})"
        kwargs = dict(type=_converter(hint, flag), default=dataclasses.MISSING, help=text.replace("%", "%%"))
        nargs = f.metadata.get("nargs")
        if nargs:  # several words; None marks "not given" (extend needs a list or None to add to)
            item = typing.get_args(_unwrap_optional(hint)[0])[:1] or (str,)
            kwargs.update(type=item[0], nargs=nargs, default=None)
            if not f.metadata.get("positional"):
                kwargs["action"] = "extend"
        elif _unwrap_optional(hint)[0] is bool and not f.metadata.get("positional"):
            kwargs.update(nargs="?", const=True, metavar="true|false")
        if "metavar" in f.metadata:
            kwargs["metavar"] = f.metadata["metavar"]
        if "choices" in f.metadata:
            kwargs["choices"] = f.metadata["choices"]
            if not nargs:
                kwargs.pop("type")
        if f.metadata.get("positional"):
            kwargs.setdefault("metavar", flag.upper())
            parser.add_argument("/".join(path), **kwargs)
        else:
            parser.add_argument(f"--{flag}", *_old_flags(cls, path, f), dest="/".join(path), **kwargs)
    parser.add_argument(
        "--config",
        dest="_config_file",
        default=None,
        metavar="FILE",
        help="JSON or YAML file of settings (nested as the log's config record); flags given on "
        "the command line override it",
    )


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
            known = [".".join(path) for path, _, _, _ in _leaves(cls)]
            raise ValueError(f"{where}: unknown setting {key!r}{suggest(key, known)}")
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
    for path, _, f, _ in _leaves(cls):
        v = getattr(ns, "/".join(path), dataclasses.MISSING)
        if f.metadata.get("nargs"):
            v = dataclasses.MISSING if v is None else tuple(v) if isinstance(v, list) else v
        if v is not dataclasses.MISSING:
            _set(values, path, v)
    return cls(**values)


class ConfigParser(argparse.ArgumentParser):
    """argparse whose errors are one line (`prog: error: ...`), without the usage block; an unknown flag names
    the flag it was renamed to (or the closest one)."""

    def error(self, message: str):
        if message.startswith("unrecognized arguments: "):
            flags = [t.split("=", 1)[0] for t in message.split(": ", 1)[1].split() if t.startswith("-")]
            known = [o for o in self._option_string_actions if o.startswith("--")]
            message = "unknown setting " + (" ".join(flags) or message.split(": ", 1)[1])
            message += suggest(flags[0], known) if flags else ""
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")

    def parse_args(self, args=None, namespace=None):
        """Unknown flags are reported by the (sub)command that was given, which knows their new spelling."""
        ns, extras = self.parse_known_args(args, namespace)
        if extras:
            getattr(ns, "_parser", self).error("unrecognized arguments: " + " ".join(extras))
        return ns


def parse_config(
    cls: type[T], argv: list[str] | None = None, prog: str | None = None, description: str | None = None
) -> T:
    """Build `cls` from the command line; a bad value exits with a one-line error naming it."""
    parser = ConfigParser(prog=prog, description=description or (cls.__doc__ or "").strip())
    add_config_arguments(parser, cls)
    ns = parser.parse_args(argv)
    try:
        return config_from_namespace(cls, ns)
    except (ValueError, OSError) as exc:
        parser.error(str(exc))
        raise  # unreachable


@dataclasses.dataclass(frozen=True)
class Command:
    """One subcommand: its config dataclass (the command line) and `run(config) -> exit code`."""

    config: type
    run: Any
    help: str = ""  # one line for the list of commands (default: the config's docstring's first sentence)
    argv: bool = False  # run(config, argv) with the whole command line (to record how an output was made)


def _add_commands(sub, commands: dict) -> None:
    for name, command in commands.items():
        if isinstance(command, dict):  # a group: `pilot maze|taxi|console`
            doc = command.get("", "")
            group = sub.add_parser(name, help=doc, description=doc)
            _add_commands(
                group.add_subparsers(dest=f"_{name}", required=True, metavar="COMMAND"),
                {k: v for k, v in command.items() if k},
            )
            continue
        doc = (command.config.__doc__ or "").strip()
        first = re.split(r"(?<!e\.g)\. |; ", " ".join(doc.split("\n\n")[0].split()))[0]  # its first sentence
        p = sub.add_parser(
            name, help=command.help or first, description=doc, formatter_class=argparse.RawDescriptionHelpFormatter
        )
        add_config_arguments(p, command.config)
        p.set_defaults(_command=command, _parser=p)


def run_commands(
    prog: str, description: str, commands: dict, argv: list[str] | None = None, moved: dict[str, str] | None = None
) -> int:
    """`prog COMMAND [SUBCOMMAND] --flags`: parse the chosen command's config and run it. `commands` maps a
    name to a `Command` or to a group (a dict of names to commands, its help under the key ""); `moved` maps a
    command that moved elsewhere to its new spelling (said in the error)."""
    given = list(sys.argv[1:] if argv is None else argv)
    if given[:1] and given[0] in (moved or {}):
        fail(f"{prog} {given[0]} moved: {(moved or {})[given[0]]}")
    parser = ConfigParser(prog=prog, description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    _add_commands(parser.add_subparsers(dest="_command_name", required=True, metavar="COMMAND"), commands)
    ns = parser.parse_args(argv)
    try:
        config = config_from_namespace(ns._command.config, ns)
    except (ValueError, OSError) as exc:
        ns._parser.error(str(exc))
    argv = list(sys.argv[1:] if argv is None else argv)
    return ns._command.run(config, argv) if ns._command.argv else ns._command.run(config)


def _flag_text(value: Any) -> str:
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, tuple):
        return ",".join(str(v) for v in value)
    return str(value)


def config_argv(config: Any) -> list[str]:
    """The flags that give `config` on its command line (each setting that differs from the default's), for a
    command written out (compose.yaml): `parse_config(type(config), config_argv(config)) == config`."""
    cls = type(config)
    try:
        base = cls()  # (a preset, e.g. the agent's, says its own values)
    except ValueError:  # a setting without a usable default
        base = None
    out: list[str] = []
    for path, flag, f, _ in _leaves(cls):
        value, default = config, base
        for name in path:
            value, default = getattr(value, name), getattr(default, name, None)
        if value == (default if base is not None else _default_at(cls, path, f)):
            continue
        if f.metadata.get("positional"):
            raise ValueError(f"config_argv: positional setting {flag!r} is not supported")
        words = [str(v) for v in value] if f.metadata.get("nargs") else [_flag_text(value)]
        out += [f"--{flag}", *words]
    return out


def config_record(config: Any) -> dict:
    """The config as a JSON-able dict (tuples become lists, nested configs nested dicts), with its type name."""
    data = dataclasses.asdict(config)
    return {"type": type(config).__name__, **json.loads(json.dumps(data))}


def fail(message: str, code: int = 2) -> None:
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(code)


def moved(now: str) -> None:
    """For a module that was a command before its command was folded into another: run as `python -m`, it says
    what replaced it (exit 2) instead of importing and exiting 0 having done nothing."""
    fail(f"this command moved: use `{now}` (docs/commands.md, 'Renamed commands')")
