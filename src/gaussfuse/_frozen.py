"""Pickling and copying frozen result dataclasses without losing their read-only arrays.

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

__all__ = ["reduce_frozen"]


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
