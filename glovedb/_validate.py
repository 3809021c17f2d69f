"""The one input check used at every public boundary.

Public functions call :func:`as_array` on their array arguments so that a caller who
passes the wrong shape or dtype gets a ``ValueError``/``TypeError`` that names the
argument, the shape it expected and the shape it got. The CLI turns these into one
line and exit code 2.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import fields
from types import EllipsisType, UnionType
from typing import Any, TypeVar, Union, get_args, get_origin, get_type_hints

import numpy as np
from numpy.typing import ArrayLike, DTypeLike, NDArray

# ``None`` in a shape spec means "any size along this axis"; ``...`` (only first) means
# "any number of leading axes".
ShapeSpec = Sequence[int | None | EllipsisType]


def _shape_text(shape: ShapeSpec) -> str:
    parts = ["..." if s is Ellipsis else ("N" if s is None else str(s)) for s in shape]
    return "(" + ", ".join(parts) + ("," if len(parts) == 1 else "") + ")"


def shape_matches(shape: tuple[int, ...], spec: ShapeSpec) -> bool:
    """Whether an array shape fits a spec such as ``(None, 20)`` or ``(..., 3, 3)``."""
    spec = list(spec)
    if spec and spec[0] is Ellipsis:
        tail = spec[1:]
        if len(shape) < len(tail):
            return False
        shape = shape[len(shape) - len(tail) :]
        spec = tail
    if len(shape) != len(spec):
        return False
    return all(s is None or s == n for s, n in zip(spec, shape, strict=True))


def as_array(
    name: str,
    value: ArrayLike,
    shape: ShapeSpec | None = None,
    dtype: DTypeLike | None = None,
    *,
    kind: str | None = None,
    finite: bool = False,
) -> NDArray:
    """Convert ``value`` to an array and check it, naming ``name`` in any error.

    Parameters
    ----------
    name : str
        Argument name used in error messages.
    value : array_like
        What the caller passed.
    shape : sequence of int, None or Ellipsis, optional
        Expected shape; ``None`` matches any size, a leading ``...`` any leading axes.
    dtype : dtype, optional
        Convert to this dtype (after the ``kind`` check).
    kind : str, optional
        Allowed numpy dtype kinds before conversion, e.g. ``"fiu"`` for numbers, ``"u"``
        for unsigned integers. A mismatch raises ``TypeError``.
    finite : bool
        Reject NaN and infinity.

    Returns
    -------
    ndarray
        The checked array (a view when no conversion was needed).
    """
    try:
        array = np.asarray(value)
    except (TypeError, ValueError) as error:
        raise TypeError(f"{name}: expected an array, got {type(value).__name__}") from error
    if kind is not None and array.dtype.kind not in kind:
        raise TypeError(f"{name}: expected dtype kind in {kind!r}, got {array.dtype}")
    if dtype is not None:
        if array.dtype.kind in "OUS":
            raise TypeError(f"{name}: expected numbers, got {array.dtype}")
        array = array.astype(dtype, copy=False)
    if shape is not None and not shape_matches(array.shape, shape):
        raise ValueError(f"{name}: expected shape {_shape_text(shape)}, got {array.shape}")
    if finite and array.dtype.kind == "f" and not np.all(np.isfinite(array)):
        raise ValueError(f"{name}: contains NaN or infinity")
    return array


def check_choice(name: str, value: str, choices: Sequence[str]) -> str:
    """Return ``value`` if it is one of ``choices``, else raise ``ValueError`` naming them."""
    if value not in choices:
        raise ValueError(f"{name}: expected one of {', '.join(map(repr, choices))}, got {value!r}")
    return value


_Config = TypeVar("_Config")


def dataclass_from_table(cls: type[_Config], table: Mapping[str, Any], where: str) -> _Config:
    """Build a (frozen) dataclass from a parsed TOML table.

    Lists become tuples; an unknown key, or a value the dataclass rejects, raises a
    ``ValueError`` that starts with ``where`` (e.g. the file and table name).
    """
    names = {f.name for f in fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(table) - names)
    if unknown:
        raise ValueError(f"{where}: unknown key {unknown[0]!r} (known: {', '.join(sorted(names))})")
    values = {k: tuple(v) if isinstance(v, list) else v for k, v in table.items()}
    hints = get_type_hints(cls)
    for key, value in values.items():
        if not _matches(value, hints[key]):
            shown = list(value) if isinstance(value, tuple) else value  # as written in TOML
            raise ValueError(f"{where}: {key}: expected {_type_name(hints[key])}, got {shown!r}")
    try:
        return cls(**values)
    except TypeError as error:
        raise ValueError(f"{where}: {error}") from error


def _matches(value: Any, hint: Any) -> bool:
    """Whether a TOML value fits a field's type (an int is a float; a bool is neither)."""
    origin, args = get_origin(hint), get_args(hint)
    if hint is Any:
        return True
    if origin in (UnionType, Union):
        return any(_matches(value, arg) for arg in args)
    if hint is type(None):
        return value is None
    if hint is bool:
        return isinstance(value, bool)
    if hint is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if hint in (int, str):
        return isinstance(value, hint) and not isinstance(value, bool)
    if origin is tuple:
        if not isinstance(value, tuple):
            return False
        if len(args) == 2 and args[1] is Ellipsis:
            return all(_matches(item, args[0]) for item in value)
        return len(value) == len(args) and all(map(_matches, value, args))
    return True  # other types are left to the dataclass


def _type_name(hint: Any) -> str:
    names = {bool: "true or false", float: "a number", int: "a whole number", str: "a string"}
    if get_origin(hint) is tuple:
        args = get_args(hint)
        if args[-1:] != (Ellipsis,):
            return f"a list of {len(args)}"
        items = {bool: "true or false", float: "numbers", int: "whole numbers", str: "strings"}
        return f"a list of {items.get(args[0], str(args[0]))}"
    return names.get(hint, str(hint).replace("typing.", ""))
