"""``gaussfuse._kernels._nrt``: borrowed arrays count no references; read-only views in."""

from __future__ import annotations

import numba
import numpy as np
from numba.extending import register_jitable

from gaussfuse._kernels._nrt import Borrowed, borrow, readonly


def _core_ir(dispatcher) -> str:
    """The LLVM IR of the compiled function itself, without numba's Python wrapper."""
    ir = dispatcher.inspect_llvm(dispatcher.signatures[0])
    bodies = [f for f in ir.split("\ndefine ")[1:] if "cpython" not in f.split("(")[0]
              and "cfunc" not in f.split("(")[0]]
    return "\n".join(bodies)


@register_jitable
def _ends(a):
    return a[0] + a[-1]


def _sum_of_ends(x):
    t = 0.0
    for k in range(x.shape[0]):  # a view a step, handed to a helper, as the kernels do
        if x[k, 0] > 2.0:
            t += _ends(x[k])
        else:
            t -= _ends(x[0])
    return t


owning = numba.njit(_sum_of_ends)
_inner = numba.njit(_sum_of_ends)


@numba.njit
def borrowed(x):
    return _inner(borrow(x))


def test_views_of_a_borrowed_array_count_no_references():
    x = np.arange(12.0).reshape(4, 3)
    assert owning(x) == borrowed(x) == sum(_ends(r) if r[0] > 2.0 else -_ends(x[0]) for r in x)
    # Owning arrays are counted, a call to NRT_incref and NRT_decref per view and helper call;
    # the same code given borrowed arrays has none.
    assert "NRT_incref" in _core_ir(owning) and "NRT_decref" in _core_ir(owning)
    assert "NRT_incref" not in _core_ir(_inner) and "NRT_decref" not in _core_ir(_inner)
    (arg,) = _inner.signatures[0]
    assert isinstance(arg, Borrowed) and arg.mutable  # one writable type for inputs and outputs


def test_a_borrowed_array_passed_as_an_array_keeps_its_values():
    @numba.njit("float64(float64[::1])")  # a fixed signature: the borrowed view is cast to it
    def first(a):
        return a[0]

    @numba.njit
    def call(x, f):
        b = borrow(x)
        return f(b[1:])  # a borrowed view, as an argument typed array

    x = np.arange(5.0)
    assert call(x, first) == 1.0


def test_readonly_is_a_contiguous_float64_view():
    a = np.arange(6, dtype=np.int32).reshape(2, 3).T
    r = readonly(a)
    assert r.dtype == np.float64 and r.flags.c_contiguous and not r.flags.writeable
    assert np.array_equal(r, a)
    b = np.zeros(3)
    assert np.shares_memory(readonly(b), b) and b.flags.writeable
