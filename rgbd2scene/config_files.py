"""Configuration files, one stack for all of them (batch builds, scene configurations).

A configuration is YAML (``.yaml``/``.yml``) or TOML (``.toml``) with the same keys either way
(:func:`read_config_file`), checked by pydantic models that refuse unknown keys (:class:`Strict`); the models
of an options dataclass derive from its fields (:func:`model_of`: settings are declared once). Every problem
is a :class:`ConfigError` whose message starts with the key path (``captures[1].scene.baseline: ...``,
:func:`validation_error` for pydantic's); the front end puts the file in front (``CONFIG: key.path: problem``)
and prints it as one line.
"""

from __future__ import annotations

import dataclasses
import typing
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, ValidationError, create_model

SUFFIXES = {".yaml": "YAML", ".yml": "YAML", ".toml": "TOML"}
TOP_LEVEL = "top level"


class ConfigError(ValueError):
    """A problem in a configuration; the message starts with the key path."""


class Strict(BaseModel):
    """A configuration mapping: unknown keys are an error, not ignored."""

    model_config = ConfigDict(extra="forbid")


def read_config_file(path: str | Path) -> dict:
    """The mapping in a YAML or TOML file (by suffix; an empty file is an empty mapping); :class:`ConfigError`
    when it cannot be read or is no mapping."""
    import tomllib

    import yaml

    path = Path(path)
    kind = SUFFIXES.get(path.suffix.lower())
    if kind is None:
        raise ConfigError(f"unknown configuration format {path.suffix!r} (use .yaml, .yml or .toml)")
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ConfigError("configuration file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"not readable ({exc})") from None
    if kind == "TOML":
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"not valid TOML ({' '.join(str(exc).split())})") from None
    else:
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
            raise ConfigError(f"not valid YAML ({where}{getattr(exc, 'problem', None) or exc})") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{TOP_LEVEL}: must be a mapping of keys, got {type(data).__name__}")
    return data


def key_path(loc, tags: dict | None = None) -> str:
    """``captures[1].scene`` from pydantic's location tuple (the tags of discriminated unions left out)."""
    out = ""
    for i, part in enumerate(loc):
        if isinstance(part, int):
            out += f"[{part}]"
        elif tags and part in tags and i > 0 and isinstance(loc[i - 1], int):
            continue
        else:
            out += ("." if out else "") + str(part)
    return out or TOP_LEVEL


def _first_model(annotation) -> type[BaseModel] | None:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in typing.get_args(annotation):
        found = _first_model(arg)
        if found is not None:
            return found
    return None


def _model_at(root: type[BaseModel], loc, tags: dict) -> type[BaseModel] | None:
    """The model that the key path ``loc`` points into (for the list of its keys)."""
    model: Any = root
    for part in loc:
        if isinstance(part, int):
            continue
        if part in tags:
            model = tags[part]
            continue
        f = model.model_fields.get(part) or next((v for v in model.model_fields.values() if v.alias == part), None)
        model = _first_model(f.annotation) if f is not None else None
        if model is None:
            return None
    return model


def validation_error(exc: ValidationError, root: type[BaseModel], tags: dict | None = None,
                     tag_key: str = "kind") -> ConfigError:
    """pydantic's first problem as a :class:`ConfigError` ``key.path: problem``: unknown keys list the known
    ones (in their declared order); ``tags`` maps the tags of a discriminated union (its ``tag_key``) to their
    models."""
    tags = tags or {}
    err = exc.errors()[0]
    loc, kind = tuple(err["loc"]), err["type"]
    if kind == "extra_forbidden":
        model = _model_at(root, loc[:-1], tags)
        known = [f.alias or name for name, f in model.model_fields.items()] if model else []
        message = "unknown key" + (f" (known: {', '.join(known)})" if known else "")
    elif kind == "missing":
        message = "required key is missing"
    elif kind in ("union_tag_invalid", "union_tag_not_found"):
        loc, message = (*loc, tag_key), f"{tag_key} must be one of {', '.join(tags)}"
    else:
        message = err["msg"].removeprefix("Value error, ")
        if "input" in err and kind != "value_error" and not isinstance(err["input"], dict | list):
            message += f", got {err['input']!r}"
    more = f" (and {exc.error_count() - 1} more problems)" if exc.error_count() > 1 else ""
    return ConfigError(f"{key_path(loc, tags)}: {message}{more}")


def model_of(cls, model_name: str, base: type[BaseModel] = Strict, exclude=(), optional: bool = False, **extra):
    """A strict pydantic model with the fields of dataclass ``cls`` (types and defaults; all None with
    ``optional``) plus ``extra`` fields: the options are declared once, in their dataclass."""
    hints = typing.get_type_hints(cls)
    fields: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if f.name in exclude:
            continue
        if optional:
            fields[f.name] = (hints[f.name] | None, None)
        else:
            default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
            fields[f.name] = (hints[f.name], default)
    fields.update(extra)
    return create_model(model_name, __base__=base, **fields)
