"""How arrays are handed to the compiled loops: read-only views in, borrowed views inside."""

from __future__ import annotations

import numpy as np
from numba.core import cgutils
from numba.extending import intrinsic

__all__ = ["borrow", "readonly"]


@intrinsic
def borrow(typingctx, arr):
    """A view of `arr` that does not own a reference to its memory.

    Numba reference-counts every array a function is given or makes (a
    view per step, the arguments of every inlined helper) with atomic
    increments and decrements, and its pruning of those pairs gives up on
    functions with loops and branches like the ones below: dozens of atomic
    operations a step, costing more than the algebra and contending between
    threads on the shared inputs. A loop function therefore borrows its own
    array arguments, which its caller keeps alive for the whole call, and
    views of a borrowed array are borrowed too. A borrowed view must never
    outlive the call that borrowed it.
    """

    def codegen(context, builder, signature, args):
        src = context.make_array(signature.args[0])(context, builder, args[0])
        view = context.make_array(signature.return_type)(context, builder)
        for field in ("data", "shape", "strides", "itemsize", "nitems"):
            setattr(view, field, getattr(src, field))
        view.meminfo = cgutils.get_null_value(view.meminfo.type)
        view.parent = cgutils.get_null_value(view.parent.type)
        return view._getvalue()

    return arr(arr), codegen


def readonly(a: np.ndarray) -> np.ndarray:
    """A read-only C-contiguous float64 view (a copy only when needed).

    Every input is passed read-only, so the kernels see one array type
    whatever the caller's flags (numba types read-only arrays separately).
    """
    a = np.ascontiguousarray(a, dtype=np.float64).view()
    a.setflags(write=False)
    return a
