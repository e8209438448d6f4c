"""How arrays are handed to the compiled loops: read-only views in, borrowed views inside."""

from __future__ import annotations

import numpy as np
from numba import types
from numba.core import cgutils
from numba.core.datamodel.models import ArrayModel
from numba.core.imputils import lower_cast
from numba.extending import intrinsic, register_model

__all__ = ["borrow", "readonly"]


class Borrowed(types.Array):
    """The type of an array that owns no reference to its memory: numba counts no references for it.

    Views of it (indexing, slicing) are borrowed too; unified with another
    borrowed array it stays borrowed, with an owning array it is an array.
    """

    def __init__(self, dtype, ndim, layout, readonly=False, name=None, aligned=True):
        super().__init__(dtype, ndim, layout, readonly=readonly, aligned=aligned,
                         name=name or f"borrowed array({dtype}, {ndim}d, {layout})")

    def copy(self, dtype=None, ndim=None, layout=None, readonly=None):
        a = super().copy(dtype, ndim, layout, readonly)
        return Borrowed(a.dtype, a.ndim, a.layout, readonly=not a.mutable, aligned=a.aligned)

    def unify(self, typingctx, other):
        a = super().unify(typingctx, other)
        if a is not None and isinstance(other, Borrowed):
            return Borrowed(a.dtype, a.ndim, a.layout, readonly=not a.mutable, aligned=a.aligned)
        return a


@register_model(Borrowed)
class _BorrowedModel(ArrayModel):
    """An array's layout, with no member that holds a reference (its meminfo is NULL)."""

    def traverse(self, builder):
        return []


@lower_cast(Borrowed, types.Array)
def _as_array(context, builder, fromty, toty, value):
    """A borrowed array passed where an array is expected (a model function's argument): the same fields.

    Its meminfo stays NULL, so the references numba counts for it are no-ops.
    """
    return value


def _borrowed_type(ty):
    """The type of a borrowed `ty`: arrays writable, tuples element by element, anything else as it is."""
    if isinstance(ty, types.Array):
        return Borrowed(ty.dtype, ty.ndim, ty.layout, readonly=False, aligned=ty.aligned)
    if isinstance(ty, types.BaseTuple):
        return types.BaseTuple.from_types([_borrowed_type(t) for t in ty], getattr(ty, "instance_class", tuple))
    return ty


def _borrowed_value(context, builder, ty, value):
    if isinstance(ty, types.Array):
        src = context.make_array(ty)(context, builder, value)
        view = context.make_array(_borrowed_type(ty))(context, builder)
        for field in ("data", "shape", "strides", "itemsize", "nitems"):
            setattr(view, field, getattr(src, field))
        view.meminfo = cgutils.get_null_value(view.meminfo.type)
        view.parent = cgutils.get_null_value(view.parent.type)
        return view._getvalue()
    if isinstance(ty, types.BaseTuple):
        out = cgutils.get_null_value(context.get_value_type(_borrowed_type(ty)))
        for i, t in enumerate(ty):
            out = builder.insert_value(out, _borrowed_value(context, builder, t, builder.extract_value(value, i)), i)
        return out
    return value


@intrinsic
def borrow(typingctx, x):
    """A view of `x` (an array, or a tuple of them) that does not own a reference to its memory.

    Numba reference-counts every array a function is given or makes (a view
    per step, every array taken from a tuple, the arguments of every helper)
    with atomic increments and decrements, and its pruning of those pairs
    gives up on functions with loops and branches like the kernels': dozens
    of atomic operations a step, costing more than the algebra and
    contending between threads on the shared inputs. A kernel therefore
    borrows its own array arguments, which its caller keeps alive for the
    whole call; views of a borrowed array are borrowed too. A borrowed view
    must never outlive the call that borrowed it.

    Borrowed arrays have a type of their own, :class:`Borrowed`, whose data
    model holds no reference: numba then emits no reference counting for them
    at all (a call to ``NRT_incref`` with a NULL meminfo is a no-op, but still
    a call, dozens a step).

    Borrowed arrays are typed writable (their memory is not touched by
    that): read-only inputs and writable outputs then share one array type,
    so each helper is compiled once for them all. The kernels never write
    to an input.
    """
    def codegen(context, builder, signature, args):
        return _borrowed_value(context, builder, signature.args[0], args[0])

    return _borrowed_type(x)(x), codegen


def readonly(a: np.ndarray) -> np.ndarray:
    """A read-only C-contiguous float64 view (a copy only when needed).

    Every input is passed read-only, so the kernels see one array type
    whatever the caller's flags (numba types read-only arrays separately).
    """
    a = np.ascontiguousarray(a, dtype=np.float64).view()
    a.setflags(write=False)
    return a
