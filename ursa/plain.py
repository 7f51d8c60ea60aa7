"""Dataclass trees as plain dicts, lists and scalars (what run directories store as YAML, and
what config hashes are computed over)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np


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
