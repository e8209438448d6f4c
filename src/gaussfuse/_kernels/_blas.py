"""BLAS and LAPACK for the compiled kernels of large states: dgemm, dtrsm, dpotrf.

SciPy exports the Fortran routines of the BLAS and LAPACK it ships
(:mod:`scipy.linalg.cython_blas`, :mod:`scipy.linalg.cython_lapack`, the
ones statsmodels calls). Importing this module registers their addresses
with LLVM under names of our own (``gaussfuse_dgemm`` ...), and the
intrinsics below call them by name. Compiled code that calls them refers to
the name, not to an address, so it can be cached on disk: a new process
imports this module (every kernel module that can run them does), which
registers the names again before the cached code is linked.

The routines are Fortran: column-major matrices, every argument by
reference. A C-contiguous (row-major) ``p × q`` array with row stride
``ld`` is, to them, the ``q × p`` column-major matrix of its transpose; the
wrappers in :mod:`._dense` do that translation.
"""

from __future__ import annotations

import llvmlite.binding as llvm
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import get_cython_function_address, intrinsic

__all__ = ["dgemm", "dtrsm", "dpotrf"]

for _module, _name in (("blas", "dgemm"), ("blas", "dtrsm"), ("lapack", "dpotrf")):
    llvm.add_symbol(f"gaussfuse_{_name}", get_cython_function_address(f"scipy.linalg.cython_{_module}", _name))

_CHAR, _INT, _DOUBLE = ir.IntType(8), ir.IntType(32), ir.DoubleType()


def _by_reference(context, builder, kinds, signature, args):
    """Each argument as the pointer Fortran expects: a char, an int or a double in a stack slot, or an array's data."""
    out = []
    for kind, ty, value in zip(kinds, signature.args, args):
        if kind == "array":
            out.append(builder.bitcast(context.make_array(ty)(context, builder, value).data,
                                       _DOUBLE.as_pointer()))
            continue
        llty = {"char": _CHAR, "int": _INT, "double": _DOUBLE}[kind]
        slot = cgutils.alloca_once(builder, llty)
        if kind == "double":
            value = context.cast(builder, value, ty, types.float64)
        else:
            value = builder.trunc(value, llty)
        builder.store(value, slot)
        out.append(slot)
    return out


def _call(name, kinds, context, builder, signature, args, info=False):
    """Call ``gaussfuse_<name>`` with `args` passed by reference as `kinds` say; LAPACK's info when `info`."""
    ptrs = _by_reference(context, builder, kinds, signature, args)
    slot = None
    if info:
        slot = cgutils.alloca_once_value(builder, _INT(0))
        ptrs.append(slot)
    fnty = ir.FunctionType(ir.VoidType(), [p.type for p in ptrs])
    builder.call(cgutils.get_or_insert_function(builder.module, fnty, f"gaussfuse_{name}"), ptrs)
    if info:
        return builder.sext(builder.load(slot), ir.IntType(64))
    return context.get_dummy_value()


_GEMM = ("char", "char", "int", "int", "int", "double", "array", "int", "array", "int", "double", "array", "int")
_TRSM = ("char", "char", "char", "char", "int", "int", "double", "array", "int", "array", "int")
_POTRF = ("char", "int", "array", "int")


@intrinsic
def dgemm(typingctx, transa, transb, m, n, k, alpha, A, lda, B, ldb, beta, C, ldc):
    """``dgemm(transa, transb, m, n, k, alpha, A, lda, B, ldb, beta, C, ldc)``: C := α op(A) op(B) + β C."""
    sig = types.void(transa, transb, m, n, k, alpha, A, lda, B, ldb, beta, C, ldc)
    return sig, lambda context, builder, signature, args: _call("dgemm", _GEMM, context, builder, signature, args)


@intrinsic
def dtrsm(typingctx, side, uplo, transa, diag, m, n, alpha, A, lda, B, ldb):
    """``dtrsm(side, uplo, transa, diag, m, n, alpha, A, lda, B, ldb)``: B := α op(A)⁻¹ B, or α B op(A)⁻¹."""
    sig = types.void(side, uplo, transa, diag, m, n, alpha, A, lda, B, ldb)
    return sig, lambda context, builder, signature, args: _call("dtrsm", _TRSM, context, builder, signature, args)


@intrinsic
def dpotrf(typingctx, uplo, n, A, lda):
    """``dpotrf(uplo, n, A, lda) -> info``: the Cholesky factor in place; info > 0 when not positive definite."""
    sig = types.int64(uplo, n, A, lda)
    return sig, lambda context, builder, signature, args: _call("dpotrf", _POTRF, context, builder, signature, args,
                                                                info=True)
