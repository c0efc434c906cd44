"""Command-line options declared on the configuration dataclasses, so that each is written once.

A field is an option when ``option()`` made it: its metadata holds the help text and, where
the command line writes it otherwise than the field's name and type say, how. ``add_options``
derives a command's flags from the fields: ``--the-name``, the type, the choices and the
default. The parser holds no default itself (``argparse.SUPPRESS``): a namespace holds
exactly the options the command line gave (``given``), and the configuration built from
them takes every other value from the dataclass. ``HelpFormatter`` shows each field's
default in ``--help``.

How a field's type becomes a flag: ``int``, ``float``, ``str`` parse as such (``X | None``
as ``X``); ``bool`` is ``--name`` / ``--no-name``; ``bool | None`` takes ``on`` or ``off``;
a tuple of fixed length takes that many values. Metadata overrides any of it with the
keywords of ``ArgumentParser.add_argument``, and ``flag`` names the option.

This module imports nothing heavy: the configuration modules that use it stay cheap to
import, and so does ``jnds --help``.
"""

from __future__ import annotations

import argparse
import dataclasses
import types
import typing


def option(default=dataclasses.MISSING, help: str = "", **cli) -> dataclasses.Field:
    """A dataclass field that is a command-line option. ``cli``: ``add_argument``'s keywords
    where the field's name and type do not say them (``flag``: the option's name, e.g.
    ``"--native"``; ``show``: a function formatting the default for ``--help``)."""
    return dataclasses.field(default=default, metadata={"help": help, **cli})


def parse_size(text: str) -> tuple[int, int]:
    """``"160x90"`` as ``(160, 90)``."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must look like 160x90, got {text!r}") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"size must be positive, got {text!r}")
    return w, h


def show_size(value: tuple[int, int]) -> str:
    return f"{value[0]}x{value[1]}"


def gib(text: str) -> int:
    """GiB (``"1.5"``) as bytes."""
    return int(float(text) * 2**30)


def on_off(text: str) -> bool:
    if text not in ("on", "off"):
        raise argparse.ArgumentTypeError(f"expected on or off, got {text!r}")
    return text == "on"


def _unwrap(tp) -> tuple[object, bool]:
    """(the type, whether None is allowed) of ``X`` or ``X | None``."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return args[0], True
    return tp, False


def options_of(cls) -> list[dataclasses.Field]:
    """The fields of dataclass ``cls`` that are options."""
    return [f for f in dataclasses.fields(cls) if "help" in f.metadata]


def add_options(parser: argparse.ArgumentParser, cls, exclude: tuple[str, ...] = ()) -> None:
    """A flag on ``parser`` for every option of dataclass ``cls`` (but ``exclude``), in the
    order of the fields. Each flag's action remembers its field (``action.field``)."""
    hints = typing.get_type_hints(cls)
    for f in options_of(cls):
        if f.name in exclude:
            continue
        meta = dict(f.metadata)
        flag = meta.pop("flag", "--" + f.name.replace("_", "-"))
        meta.pop("show", None)
        kind, optional = _unwrap(hints[f.name])
        kw: dict = dict(dest=f.name, default=argparse.SUPPRESS, help=meta.pop("help").replace("%", "%%"))
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            kw["required"] = True
        if kind is bool and optional:
            kw.update(type=on_off, metavar="{on,off}")
        elif kind is bool:
            kw["action"] = argparse.BooleanOptionalAction
        elif typing.get_origin(kind) is tuple and "type" not in meta:
            args = typing.get_args(kind)
            kw["type"] = args[0]
            if args[-1] is not Ellipsis:
                kw["nargs"] = len(args)
        else:
            kw["type"] = kind
        kw.update(meta)
        if kw.get("action") in ("store_true", "store_false"):
            kw.pop("type", None)
        action = parser.add_argument(flag, **kw)
        action.field = f


def given(args: argparse.Namespace, cls) -> dict:
    """The options of dataclass ``cls`` that the command line gave (``add_options``), tuples
    where the field is one."""
    hints = typing.get_type_hints(cls)
    out = {}
    for f in options_of(cls):
        if hasattr(args, f.name):
            v = getattr(args, f.name)
            tuple_field = typing.get_origin(_unwrap(hints[f.name])[0]) is tuple
            out[f.name] = tuple(v) if tuple_field and isinstance(v, list) else v
    return out


def shown_default(action: argparse.Action) -> str | None:
    """The default ``--help`` shows for ``action``, or None where it shows none (a required
    option, a default of None or nothing, a flag that is off unless given)."""
    f = getattr(action, "field", None)
    if f is not None:
        if action.required or f.default is dataclasses.MISSING:
            return None
        value = f.default
    else:
        value = action.default
    if value is None or value is argparse.SUPPRESS or action.required or value in ((), []):
        return None
    if isinstance(action, argparse.BooleanOptionalAction):
        return action.option_strings[0 if value else 1]
    if isinstance(value, bool):  # store_true / store_false: the flag says what it changes
        return None
    if f is not None and "show" in f.metadata:
        return f.metadata["show"](value)
    if isinstance(value, (tuple, list)):
        return " ".join(map(str, value))
    return str(value)


class HelpFormatter(argparse.HelpFormatter):
    """Each option's help ends with its default (``shown_default``)."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = shown_default(action)
        if default is None or "%(default)" in text:
            return text
        return f"{text} (default: {default.replace('%', '%%')})".lstrip()
