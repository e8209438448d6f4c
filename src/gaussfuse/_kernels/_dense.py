r"""Dense matrix products and Cholesky solves for the compiled kernels: loops, or BLAS when large.

The compiled Kalman algebra (:mod:`._step`, :mod:`._slr`) is written once,
in terms of the operations here, on C-contiguous float64 arrays whose
leading blocks are used (explicit sizes, so that a block of the observed
components needs no view):

==========================================  ==========================================
``matmul(A, B, C, p, q, r)``                ``C[:p, :r] = A[:p, :q] @ B[:q, :r]``
``congruence(B, P, Y, out, BP, k, n)``      ``BP = B P``, ``out = sym(BP Bᵀ + Y)``: the k × k
                                            congruence of the n × n ``P`` by the k × n ``B``
``cholesky(S, L, p) -> bool``               ``L[:p, :p]``: the lower Cholesky factor of ``S[:p, :p]``
``roundoff_pivot(L, S, p) -> bool``         whether that factor has a pivot of round-off
``cho_solve(L, X, p, r)``                   ``X[:p, :r] = (L Lᵀ)⁻¹ X``, two triangular solves
``negative_variance(P, n) -> bool``         whether ``P`` has a variance below 0 (and no inf or NaN)
``abs_congruence_diagonal(A, X, t, ...)``   ``t = diag(|A| |X| |A|ᵀ)`` (or added to t): the size of the terms
                                            of a congruence, on which its round-off is judged
``clip_variances(P, t, n)``                 the row and column of a zero variance computed below 0 set to 0
==========================================  ==========================================

Every covariance the filters form is a :func:`congruence`: the prediction
:math:`A P A^\top + Q`, the innovation covariance :math:`H P H^\top + R`,
both terms of the Joseph form, the smoother's :math:`P + G D G^\top`;
``sym(X) = (X + Xᵀ) / 2`` is :func:`gaussfuse._linalg.symmetrize`.

Each is explicit loops for small operands (what is fast for a handful of
rows, where a library call costs more than the arithmetic) and a call of
BLAS or LAPACK (:mod:`._blas`: ``dgemm``, ``dtrsm``, ``dpotrf``, what is
fast for dozens) from :data:`BLAS_FROM` rows on, decided at run time
(and only for C-contiguous operands, which every kernel array is; others
take the loops). The
calls are plain external calls: they cost next to nothing to compile, so a
kernel has one variant for every size.

Like LAPACK's ``potrf``, :func:`cholesky` fails (returns False) at the first
pivot that is not positive, or NaN: the matrix is not positive definite.
Only the lower triangle of L is written and read.
"""

from __future__ import annotations

import math

from numba.extending import register_jitable

from ._blas import dgemm, dpotrf, dtrsm

__all__ = ["matmul", "congruence", "cholesky", "roundoff_pivot", "cho_solve", "BLAS_FROM"]

BLAS_FROM = 16
"""Products of at least ``BLAS_FROM**3`` multiply-adds (``p q r``), and factorisations and solves of
``BLAS_FROM`` rows or more, call BLAS and LAPACK; smaller ones are loops (see ``benchmarks/``, W5)."""
_BLAS_WORK = BLAS_FROM**3

_JIT = {"error_model": "numpy"}
_EPS = 2.0**-52  # float64's machine epsilon
# Fortran's option characters, as the integers the BLAS wrappers pass.
_N, _T, _U, _R = ord("N"), ord("T"), ord("U"), ord("R")

# A row-major p × q block with row stride ld is, to Fortran, the column-major
# q × p matrix of its transpose, with leading dimension ld.


@register_jitable(**_JIT)
def _rows(A):
    """Whether A's rows are contiguous and evenly spaced by its row length, as the BLAS calls assume."""
    return A.strides[1] == A.itemsize and A.strides[0] == A.shape[1] * A.itemsize


@register_jitable(**_JIT)
def matmul(A, B, C, p, q, r):
    """``C[:p, :r] = A[:p, :q] @ B[:q, :r]``."""
    if p * q * r >= _BLAS_WORK and _rows(A) and _rows(B) and _rows(C):  # Cᵀ = Bᵀ Aᵀ, column-major
        dgemm(_N, _N, r, p, q, 1.0, B, B.shape[1], A, A.shape[1], 0.0, C, C.shape[1])
        return
    for i in range(p):
        for j in range(r):
            t = 0.0
            for c in range(q):
                t += A[i, c] * B[c, j]
            C[i, j] = t


@register_jitable(**_JIT)
def congruence(B, P, Y, out, BP, k, n):
    """``BP[:k, :n] = B[:k, :n] @ P[:n, :n]`` and ``out[:k, :k] = sym(BP Bᵀ + Y)`` (Y: k × k, or None).

    P (and Y) must be exactly symmetric, as every covariance here is: the
    loops then read rows where the product has columns (``P[c, j] = P[j, c]``).
    Both compute the whole product and average it with its transpose, as the
    readable path does: the loops once mirrored one triangle, whose round-off
    is one-sided (audit Z4: under a prior 1e12 times the sensor's, 14 and 15
    states lost positive definiteness where the readable path and BLAS, from
    16 states, did not).
    """
    if k * n * n < _BLAS_WORK or not (_rows(B) and _rows(P) and _rows(out) and _rows(BP)):
        for i in range(k):
            for j in range(n):  # row i of B P, by dot products of rows
                t = 0.0
                for c in range(n):
                    t += B[i, c] * P[j, c]
                BP[i, j] = t
            for j in range(i + 1):  # entries (i, j) and (j, i) of (B P) Bᵀ + Y, averaged (rows j <= i of BP are done)
                x = 0.0
                y = 0.0
                for c in range(n):
                    x += BP[i, c] * B[j, c]
                    y += BP[j, c] * B[i, c]
                if Y is not None:
                    x += Y[i, j]
                    y += Y[j, i]
                out[i, j] = 0.5 * x + 0.5 * y  # as _linalg.symmetrize: no overflow of x + y
                out[j, i] = out[i, j]
        return
    matmul(B, P, BP, k, n, n)
    # out = (B P) Bᵀ: to Fortran, outᵀ = B (B P)ᵀ, B used transposed
    dgemm(_T, _N, k, k, n, 1.0, B, B.shape[1], BP, BP.shape[1], 0.0, out, out.shape[1])
    for i in range(k):
        for j in range(i + 1):
            x = out[i, j] + (0.0 if Y is None else Y[i, j])
            y = out[j, i] + (0.0 if Y is None else Y[j, i])
            out[i, j] = 0.5 * x + 0.5 * y  # as _linalg.symmetrize: no overflow of x + y
            out[j, i] = out[i, j]


@register_jitable(**_JIT)
def negative_variance(P, n):
    """Whether ``P[:n, :n]`` has a variance below 0 and no inf or NaN (an overflow to report, not to clip)."""
    negative = False
    for j in range(n):
        negative = negative or P[j, j] < 0.0
    if not negative:
        return False
    for j in range(n):
        for c in range(n):
            if not math.isfinite(P[j, c]):
                return False
    return True


@register_jitable(**_JIT)
def abs_congruence_diagonal(A, X, t, n, k, add):
    """``t[:n] (+)= diag(|A[:n, :k]| |X[:k, :k]| |A[:n, :k]|ᵀ)``: the size of the terms of ``A X Aᵀ``."""
    for j in range(n):
        total = 0.0
        for a in range(k):
            if A[j, a] != 0.0:
                row = 0.0
                for b in range(k):
                    row += abs(X[a, b]) * abs(A[j, b])
                total += abs(A[j, a]) * row
        t[j] = t[j] + total if add else total


@register_jitable(**_JIT)
def clip_variances(P, t, n):
    """_linalg.clip_variances, given the terms' sizes ``t[:n]`` (:func:`abs_congruence_diagonal`): the row and
    column of each variance below 0 whose row is all within ``16 n ε √(t_i t_j)`` of 0 set to 0. Rows are judged
    one by one; a row set to 0 was within the bound of the rows after it."""
    tol = 16.0 * n * _EPS
    for j in range(n):
        if P[j, j] < 0.0:
            quiet = True
            for c in range(n):
                if abs(P[j, c]) > tol * math.sqrt(t[j]) * math.sqrt(t[c]):  # (t_j t_c overflows past 1e154)
                    quiet = False
            if quiet:
                for c in range(n):
                    P[j, c] = 0.0
                    P[c, j] = 0.0


@register_jitable(**_JIT)
def cholesky(S, L, p):
    """The lower Cholesky factor of ``S[:p, :p]`` into ``L[:p, :p]``; False if S is not positive definite."""
    if p >= BLAS_FROM and _rows(L):
        for i in range(p):
            for j in range(i + 1):
                L[i, j] = S[i, j]
        # Row-major lower L is Fortran's upper U = Lᵀ, with S = Uᵀ U.
        if dpotrf(_U, p, L, L.shape[1]) != 0:
            return False
        for j in range(p):  # some LAPACKs pass a NaN pivot: refuse it as the loops do
            if not L[j, j] > 0.0:
                return False
        return True
    for j in range(p):
        d = S[j, j]
        for c in range(j):
            d -= L[j, c] * L[j, c]
        if not d > 0.0:  # potrf's test: a zero, negative or NaN pivot
            return False
        d = math.sqrt(d)
        L[j, j] = d
        for i in range(j + 1, p):
            t = S[i, j]
            for c in range(j):
                t -= L[i, c] * L[j, c]
            L[i, j] = t / d
    return True


@register_jitable(**_JIT)
def roundoff_pivot(L, S, p):
    r"""_linalg.roundoff_pivot: whether some :math:`L_{jj}^2 \le 2 (j + 1) \epsilon S_{jj}` (j < p)."""
    for j in range(p):
        if L[j, j] * L[j, j] <= 2 * (j + 1) * _EPS * S[j, j]:
            return True
    return False


@register_jitable(**_JIT)
def cho_solve(L, X, p, r):
    """``X[:p, :r] = (L Lᵀ)⁻¹ X[:p, :r]`` with L lower triangular: forward, then back substitution."""
    if p >= BLAS_FROM and _rows(L) and _rows(X):
        # Xᵀ (Fortran's r × p matrix Y) := Y L⁻ᵀ L⁻¹ = Y U⁻¹ U⁻ᵀ, with U = Lᵀ as Fortran sees L.
        dtrsm(_R, _U, _N, _N, r, p, 1.0, L, L.shape[1], X, X.shape[1])
        dtrsm(_R, _U, _T, _N, r, p, 1.0, L, L.shape[1], X, X.shape[1])
        return
    for a in range(p):  # L Y = X, row by row
        for b in range(a):
            f = L[a, b]
            for c in range(r):
                X[a, c] -= f * X[b, c]
        d = L[a, a]
        for c in range(r):
            X[a, c] /= d
    for a in range(p - 1, -1, -1):  # Lᵀ Z = Y
        for b in range(a + 1, p):
            f = L[b, a]
            for c in range(r):
                X[a, c] -= f * X[b, c]
        d = L[a, a]
        for c in range(r):
            X[a, c] /= d
