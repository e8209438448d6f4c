"""Pickling, copying and showing frozen result dataclasses.

A NumPy array comes back writable from ``copy.deepcopy`` and from a pickle
of protocol 4 or lower (the default before Python 3.14, and what
:mod:`multiprocessing` uses), so the default protocol would hand back a
result whose arrays can be changed where the original's could not. A result
class sets ``__reduce__ = reduce_frozen``: it is rebuilt by its constructor
from its fields, and the arrays that were read-only are made read-only again.
"""

from __future__ import annotations

from dataclasses import fields

import numpy as np

__all__ = ["reduce_frozen", "shapes_repr"]


def reduce_frozen(obj) -> tuple:
    """``__reduce__`` for a frozen dataclass whose ``__init__`` takes its fields in order.

    Parameters
    ----------
    obj : dataclass instance

    Returns
    -------
    tuple
        ``(rebuild, (type(obj), values, readonly))``: the field values, and
        the positions of those that are read-only arrays.
    """
    values = tuple(getattr(obj, f.name) for f in fields(obj))
    readonly = tuple(i for i, v in enumerate(values) if isinstance(v, np.ndarray) and not v.flags.writeable)
    return _rebuild, (type(obj), values, readonly)


def _rebuild(cls: type, values: tuple, readonly: tuple[int, ...]):
    """``cls(*values)`` with the arrays at the positions `readonly` made read-only."""
    for i in readonly:
        values[i].setflags(write=False)
    return cls(*values)


def shapes_repr(obj) -> str:
    """``__repr__`` for a result dataclass: its arrays by shape, its numbers by value, its None fields left out.

    A result of 10⁶ steps prints as one line, not as its arrays.
    """
    parts = []
    for f in fields(obj):
        value = getattr(obj, f.name)
        if value is None:
            continue
        if isinstance(value, np.ndarray) and value.ndim:
            parts.append(f"{f.name}: {value.shape}")
        elif isinstance(value, (float, np.floating)) or (isinstance(value, np.ndarray) and value.ndim == 0):
            parts.append(f"{f.name}={float(value):.6g}")
        elif isinstance(value, (bool, int, str, np.integer)):
            parts.append(f"{f.name}={value!r}")
        else:
            parts.append(f"{f.name}: {type(value).__name__}")
    return f"{type(obj).__name__}({', '.join(parts)})"
