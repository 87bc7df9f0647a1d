"""Options declared once: a stage's settings are one dataclass whose fields carry their help text.

From that one declaration derive the command-line flags (:func:`add_arguments`, :func:`from_args`), the
configuration keys of a batch build (:func:`from_mapping`, unknown keys are an error), the task file
handed to Blender and the records in ``scene.json`` / ``dataset.json`` (:func:`to_record`), and the resume
check (:func:`resume_diff` compares the fields marked ``resume=True``).

A field's CLI flag is ``--name-with-dashes`` unless ``flag=`` says otherwise; a boolean that defaults to
True gets a ``--no-...`` flag. A field marked ``file=True`` holds a file path (or a list of them), which a
configuration file gives relative to itself (:func:`from_mapping`'s ``base_dir``). A field with ``nargs`` takes
several values: ``nargs=2`` on a ``tuple[float, float]`` field is ``--depth-range MIN MAX`` on the command line
and ``depth_range: [0.02, 0.5]`` in a configuration file; ``nargs="+"`` on a ``list[str]`` field takes one or
more. ``group`` names the ``--help`` section of a flag.

Problems found by the library are :class:`OptionError`\\ s naming the field, which the CLI reports with the
flag and a batch build with the configuration key (:meth:`OptionError.render`).

A field whose default is itself an options dataclass is a nested record (e.g. the render stage's ``sensor``):
its fields get flags of their own (in an argument group named after it), a configuration gives it as a
mapping (``render: {sensor: {noise: false}}``), records hold it as a dict, and an error in it is named with
a dotted path (``sensor.ae_speed``), which :func:`flag_of` resolves to the nested field's flag.
"""

from __future__ import annotations

import argparse
import dataclasses
import re
import typing
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

#: ``{field}`` in an :class:`OptionError` message: a field the sentence names, spelled by each front end.
_FIELD = re.compile(r"\{([a-z][a-z0-9_]*)\}")


class OptionError(ValueError):
    """An invalid option value; ``name`` is the field, so each front end can name its own spelling.

    A message that names fields itself (``"give {rgb} and {depth}"``) is a whole sentence: :meth:`render`
    spells the fields in it instead of prefixing ``name``.
    """

    def __init__(self, name: str, message: str):
        super().__init__(message)
        self.name = name
        self.message = message

    def render(self, spell: Callable[[str], str] = str, where: str = "") -> str:
        """The message for one front end: ``spell`` turns a field name into its spelling (``--depth-range``,
        ``depth_range``); ``where`` (a configuration key path such as ``captures[2]``) goes before it."""
        if _FIELD.search(self.message):
            text = _FIELD.sub(lambda m: spell(m[1]), self.message)
            return f"{where}: {text}" if where else text
        return f"{where}.{spell(self.name)}: {self.message}" if where else f"{spell(self.name)}: {self.message}"


def option(default: Any = None, help: str = "", *, flag: str | None = None, choices=None,
           parse: Callable[[str], Any] | None = None, resume: bool = False, cli: bool = True,
           metavar: str | tuple[str, ...] | None = None, file: bool = False, nargs: int | str | None = None,
           group: str | None = None) -> Any:
    """A dataclass field with what the CLI and the records need to know about it.

    ``parse`` turns the command-line (or configuration) text into the value (e.g. ``"512x256"`` -> (512, 256));
    ``resume`` marks settings that must match for a re-run to continue into the same output folder;
    ``cli=False`` keeps a field out of the command line (set by the program, or by configuration files);
    ``file=True`` marks a file path (resolved against a configuration file's folder);
    ``nargs`` (an int, or ``"+"``) makes a flag take several values (the field is a tuple or list; ``metavar``
    may name each, e.g. ``("MIN", "MAX")``); ``group`` is the flag's section in ``--help``.
    """
    meta = {"help": help, "flag": flag, "choices": choices, "parse": parse, "resume": resume, "cli": cli,
            "metavar": metavar, "file": file, "nargs": nargs, "group": group}
    if isinstance(default, (list, dict, set)):
        return dataclasses.field(default_factory=lambda: type(default)(default), metadata=meta)
    if dataclasses.is_dataclass(default):  # a nested record: each instance gets its own copy
        return dataclasses.field(default_factory=lambda: dataclasses.replace(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def nested_records(cls) -> dict[str, type]:
    """Fields of ``cls`` that are nested option records -> their dataclass."""
    out = {}
    for f in dataclasses.fields(cls):
        if f.default_factory is not dataclasses.MISSING:
            value = f.default_factory()
            if dataclasses.is_dataclass(value):
                out[f.name] = type(value)
    return out


def flag_of(cls, name: str) -> str:
    """The command-line flag of field ``name`` (for error messages; ``record.field`` for a nested record's)."""
    if "." in name:
        head, rest = name.split(".", 1)
        return flag_of(nested_records(cls)[head], rest)
    f = {f.name: f for f in dataclasses.fields(cls)}[name]
    if f.metadata.get("flag"):
        return f.metadata["flag"]
    if f.default is True:
        return "--no-" + name.replace("_", "-")
    return "--" + name.replace("_", "-")


def _base_type(cls, f) -> type | None:
    hint = typing.get_type_hints(cls).get(f.name)
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    base = args[0] if args else hint
    base = typing.get_origin(base) or base
    return base if isinstance(base, type) else None


def _element_type(cls, f) -> type | None:
    """The type of each value of a several-value field (``tuple[float, float]`` -> float)."""
    hint = typing.get_type_hints(cls).get(f.name)
    for arg in [a for a in typing.get_args(hint) if a is not type(None)] or [hint]:
        inner = [a for a in typing.get_args(arg) if a is not Ellipsis]
        if typing.get_origin(arg) in (list, tuple) and inner and isinstance(inner[0], type):
            return inner[0]
    return None


def _is_tuple(cls, f) -> bool:
    hint = typing.get_type_hints(cls).get(f.name)
    return any(typing.get_origin(a) is tuple for a in (hint, *typing.get_args(hint)))


def _describe_default(value) -> str:
    if isinstance(value, tuple) and len(value) == 2 and all(isinstance(v, int) for v in value):
        return f"{value[0]}x{value[1]}"
    if isinstance(value, (tuple, list)):
        return " ".join(map(str, value))
    return str(value)


def _argparse_type(parse: Callable[[str], Any]) -> Callable[[str], Any]:
    """``parse`` for argparse: its ValueError message becomes the flag's error message."""
    def convert(text: str):
        try:
            return parse(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    convert.__name__ = parse.__name__
    return convert


def add_arguments(parser: argparse.ArgumentParser | argparse._ArgumentGroup, cls, exclude=()) -> None:
    """Add one flag per CLI field of the options dataclass ``cls`` (defaults and help from the fields); fields
    with a ``group`` go to that section of ``--help`` (created on ``parser`` when it is a parser), and a nested
    record's fields go in an argument group of their own."""
    sections: dict[str, Any] = {}
    nested = nested_records(cls)
    for f in dataclasses.fields(cls):
        meta = f.metadata
        if not meta.get("cli", True) or f.name in exclude:
            continue
        if f.name in nested:
            if isinstance(parser, argparse._ArgumentGroup):  # argparse groups do not nest
                add_arguments(parser, nested[f.name])
            else:
                add_arguments(parser.add_argument_group(f.name, meta.get("help") or None), nested[f.name])
            continue
        target = parser
        if meta.get("group") and isinstance(parser, argparse.ArgumentParser):
            target = sections.get(meta["group"]) or sections.setdefault(meta["group"],
                                                                         parser.add_argument_group(meta["group"]))
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        help_text = meta.get("help", "")
        flag = flag_of(cls, f.name)
        if isinstance(default, bool):
            action = "store_false" if default else "store_true"
            target.add_argument(flag, dest=f.name, action=action, default=default, help=help_text)
            continue
        nargs = meta.get("nargs")
        if meta.get("parse"):
            kind = _argparse_type(meta["parse"])
        else:
            kind = _element_type(cls, f) if nargs else _base_type(cls, f)
        if kind in (list, tuple, dict):
            kind = None
        if default is not None and help_text and "default" not in help_text:
            help_text = f"{help_text} (default {_describe_default(default)})"
        metavar = meta.get("metavar") or (None if meta.get("choices") else flag.lstrip("-").upper().replace("-", "_"))
        target.add_argument(flag, dest=f.name, type=kind, default=default, choices=meta.get("choices"),
                            help=help_text, metavar=metavar, nargs=nargs)


def flags_of(parser: argparse.ArgumentParser) -> dict[str, str]:
    """Field (``dest``) -> its long flag, for every option of ``parser`` (to spell :class:`OptionError`\\ s)."""
    return {a.dest: max(a.option_strings, key=len) for a in parser._actions if a.option_strings}


def from_args(cls, args: argparse.Namespace, **overrides):
    """The options dataclass from parsed arguments (fields without a flag keep their defaults; several values
    of a tuple field become a tuple; nested records from their own flags)."""
    nested = nested_records(cls)
    values = {}
    for f in dataclasses.fields(cls):
        if hasattr(args, f.name) and f.name not in nested:
            value = getattr(args, f.name)
            values[f.name] = tuple(value) if isinstance(value, list) and _is_tuple(cls, f) else value
    values.update({f.name: from_args(nested[f.name], args) for f in dataclasses.fields(cls)
                   if f.name in nested and f.metadata.get("cli", True)})
    values.update(overrides)
    return cls(**values)


def from_mapping(cls, values: Mapping[str, Any], where: str = "", base_dir: str | Path | None = None):
    """The options dataclass from a configuration mapping (YAML, TOML, JSON).

    Unknown keys, values of the wrong type (checked against the field's annotation with pydantic: ``"0.5"``
    is read as a float, ``1.5`` is no int) and values outside a field's ``choices`` are
    :class:`OptionError`\\ s naming ``where.key``. String values go through the field's ``parse`` first;
    relative paths of ``file=True`` fields are taken relative to ``base_dir`` when given.
    """
    from pydantic import TypeAdapter, ValidationError

    names = {f.name: f for f in dataclasses.fields(cls)}
    prefix = f"{where}." if where else ""
    if not isinstance(values, Mapping):
        raise OptionError(where, f"must be a mapping of {cls.__name__} keys, got {values!r}")
    unknown = sorted(set(values) - set(names))
    if unknown:
        raise OptionError(prefix + unknown[0], f"unknown key (known: {', '.join(sorted(names))})")
    hints = typing.get_type_hints(cls)
    nested = nested_records(cls)
    kwargs = {}
    for key, value in values.items():
        meta = names[key].metadata
        if key in nested:
            if not dataclasses.is_dataclass(value):
                value = from_mapping(nested[key], value, prefix + key, base_dir)
            kwargs[key] = value
            continue
        parse = meta.get("parse")
        if parse is not None and isinstance(value, str):
            try:
                value = parse(value)
            except (ValueError, argparse.ArgumentTypeError) as exc:
                raise OptionError(prefix + key, str(exc)) from None
        try:
            value = TypeAdapter(hints[key]).validate_python(value)
        except ValidationError as exc:
            first = exc.errors()[0]
            raise OptionError(prefix + key, f"{first['msg']}, got {value!r}") from None
        if meta.get("choices") and value not in meta["choices"]:
            raise OptionError(prefix + key, f"choose one of {', '.join(map(str, meta['choices']))}, got {value!r}")
        if meta.get("file") and value is not None and base_dir is not None:
            value = _relative_to(base_dir, value)
        kwargs[key] = value
    return cls(**kwargs)


def _relative_to(base_dir: str | Path, value):
    """A path (or list of paths) of a configuration file, relative to its folder."""
    if isinstance(value, (list, tuple)):
        return type(value)(_relative_to(base_dir, v) for v in value)
    return str(Path(base_dir) / Path(value).expanduser())


def to_record(options) -> dict:
    """JSON-ready dict of every field (tuples as lists; nested dataclasses through their ``to_dict``)."""
    out = {}
    for f in dataclasses.fields(options):
        value = getattr(options, f.name)
        if hasattr(value, "to_dict"):
            value = value.to_dict()
        elif isinstance(value, tuple):
            value = list(value)
        out[f.name] = value
    return out


def resume_diff(options, record: Mapping[str, Any]) -> list[str]:
    """Names of the ``resume=True`` fields whose value differs from ``record`` (a :func:`to_record` dict)."""
    now = to_record(options)
    return [f.name for f in dataclasses.fields(options)
            if f.metadata.get("resume") and record.get(f.name) != now[f.name]]
