"""Base of openemt's result dataclasses: ``to_dict()`` for JSON, attributes for Python.

A result is a frozen dataclass deriving from :class:`Result`. Its fields are read as attributes;
``to_dict()`` gives the JSON-ready dict (nested results, arrays and NumPy scalars converted to
plain Python) that the command line prints with ``--json``. Indexing a result like a dict
(``result["key"]``) still works for a deprecation period and warns.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from typing import Any, ClassVar

import numpy as np

__all__ = ["DictResult", "Result", "json_ready", "plain"]


def plain(value: Any) -> Any:
    """``value`` with results, mappings, sequences, arrays and NumPy scalars made plain Python
    (results through their ``to_dict()``); other values are returned as they are."""
    if isinstance(value, Result):
        return value.to_dict()
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def json_ready(value: Any) -> Any:
    """:func:`plain` ``value`` for strict JSON: non-finite floats become None (null), paths
    strings."""
    value = plain(value)
    if isinstance(value, dict):
        return {k: json_ready(v) for k, v in value.items()}
    if isinstance(value, list):
        return [json_ready(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return str(value) if hasattr(value, "__fspath__") else value


class Result:
    """Mixin of the result dataclasses.

    Subclasses list the fields left out of ``to_dict()`` (per-row arrays) in ``_not_in_dict``,
    and override :meth:`_items` when their dict layout differs from their fields.
    """

    __slots__ = ()
    _not_in_dict: ClassVar[tuple[str, ...]] = ()
    __iter__ = None  # not a container: item access below is only kept for old code

    def _items(self) -> dict:
        """Key -> value in the order of ``to_dict()``, values as stored."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                if f.name not in self._not_in_dict}

    def to_dict(self) -> dict:
        """The result as a JSON-ready dict."""
        return {k: plain(v) for k, v in self._items().items()}

    def __getitem__(self, key: str):
        warnings.warn(f"indexing a {type(self).__name__} like a dict is deprecated; use its "
                      f"attributes or .to_dict()[{key!r}]", DeprecationWarning, stacklevel=2)
        if dataclasses.is_dataclass(self) and key in {f.name for f in dataclasses.fields(self)}:
            return getattr(self, key)
        return self._items()[key]


class DictResult(Result, dict):
    """A result that is also a read-only dict of its ``to_dict()``.

    For results that were plain dicts before: code that indexes them, iterates over them or
    serialises them with ``json.dumps`` keeps working. The dataclass fields are the API.
    """

    __slots__ = ()

    def __post_init__(self):
        dict.update(self, self.to_dict())

    __getitem__ = dict.__getitem__
    __iter__ = dict.__iter__

    def __reduce__(self):
        # rebuilt from the fields (copy, pickle), not by setting items
        return type(self), tuple(getattr(self, f.name) for f in dataclasses.fields(self))

    def _read_only(self, *args, **kwargs):
        raise TypeError(f"{type(self).__name__} is read-only")

    __setitem__ = __delitem__ = _read_only
    clear = pop = popitem = setdefault = update = _read_only
    __ior__ = _read_only
