"""Dataclass trees as plain dicts, lists and scalars (what run directories store as YAML, and
what config hashes are computed over), and back: :func:`to_plain` and its inverse
:func:`from_plain` (dacite)."""

from __future__ import annotations

import dataclasses
import types
import typing
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypeVar

import dacite
import numpy as np

T = TypeVar("T")


def to_plain(obj: Any) -> Any:
    """Dataclass tree -> plain dicts, lists and scalars."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, dict):
        return {str(k): to_plain(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [to_plain(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def from_plain(cls: type[T], data: Any) -> T:
    """Rebuild a dataclass ``cls`` from :func:`to_plain`'s output.

    Nested dataclasses, tuples (lists in YAML), ``X | None``, ``Literal``, ``Path`` and plain
    scalars are converted and checked by the field's annotation (an ``int`` where a ``float`` is
    declared becomes a float, an integral float where an ``int`` is declared an int). Missing
    fields keep their defaults; unknown keys, at any depth, are dropped with one warning naming
    them (a config written by a newer version still loads). A value outside a ``Literal``'s
    choices, or a fixed-length tuple of another length, raises ``ValueError``; any other
    mismatch ``TypeError``.
    """
    if not isinstance(data, Mapping):
        raise TypeError(f"{cls.__name__}: expected a mapping, got {type(data).__name__}")
    unknown: list[str] = []
    known = _drop_unknown(cls, data, "", unknown)
    if unknown:
        warnings.warn(f"{cls.__name__}: ignoring unknown config keys {unknown}", stacklevel=2)
    try:
        return dacite.from_dict(cls, known, _DACITE)
    except dacite.WrongTypeError as e:
        raise _mismatch(f"{cls.__name__}.{e.field_path}", e.field_type, e.value) from None
    except dacite.DaciteError as e:
        raise TypeError(f"{cls.__name__}: {e}") from None


def _to_float(value: Any) -> Any:
    if isinstance(value, bool):  # an int to Python, but never a float in a config
        raise TypeError(f"expected float, got {value!r}")
    return float(value) if isinstance(value, int) else value


def _to_int(value: Any) -> Any:
    return int(value) if isinstance(value, float) and value.is_integer() else value


#: Scalars by annotation, tuples from lists, paths from strings; dacite checks the rest. (The
#: items of a list read as a fixed-length tuple are built by the tuple's first item type:
#: the configs' tuples all have one item type.)
_DACITE = dacite.Config(type_hooks={float: _to_float, int: _to_int}, cast=[tuple, Path])


def _mismatch(where: str, tp: Any, value: Any) -> Exception:
    """``ValueError`` for a value outside a ``Literal``'s choices or a fixed-length tuple of
    another length, ``TypeError`` for any other mismatch."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is typing.Literal:
        return ValueError(f"{where}: {value!r} is not one of {args}")
    fixed = origin is tuple and not (len(args) == 2 and args[1] is Ellipsis)
    if fixed and isinstance(value, tuple) and len(value) != len(args):
        return ValueError(f"{where}: expected {len(args)} items, got {len(value)}")
    return TypeError(f"{where}: cannot convert {value!r} to {tp}")


def _drop_unknown(tp: Any, data: Any, path: str, unknown: list[str]) -> Any:
    """``data`` without the keys that no (init) field of the dataclasses in ``tp`` takes; their
    dotted paths are added to ``unknown``."""
    if dataclasses.is_dataclass(tp) and isinstance(tp, type) and isinstance(data, Mapping):
        hints = typing.get_type_hints(tp)
        fields = {f.name: hints[f.name] for f in dataclasses.fields(tp) if f.init}
        unknown += sorted(path + str(k) for k in data if k not in fields)
        return {
            k: _drop_unknown(fields[k], v, f"{path}{k}.", unknown)
            for k, v in data.items()
            if k in fields
        }
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType) and isinstance(data, Mapping):  # X | None
        inner = [a for a in args if dataclasses.is_dataclass(a)]
        return _drop_unknown(inner[0], data, path, unknown) if len(inner) == 1 else data
    if origin in (list, tuple) and args and isinstance(data, list | tuple):
        variadic = origin is list or (len(args) == 2 and args[1] is Ellipsis)
        kinds = [args[0]] * len(data) if variadic else list(args)
        known = [
            _drop_unknown(k, v, f"{path}{i}.", unknown)
            for i, (k, v) in enumerate(zip(kinds, data, strict=False))
        ]
        return known + list(data[len(known) :])
    return data
