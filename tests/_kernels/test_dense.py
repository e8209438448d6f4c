"""The products and Cholesky solves of :mod:`gaussfuse._kernels._dense`, loops and BLAS, equal NumPy's.

Sizes on both sides of :data:`~gaussfuse._kernels._dense.BLAS_FROM` run the
loops and the BLAS and LAPACK calls of :mod:`gaussfuse._kernels._blas`; the
operands are the leading blocks of larger arrays, as the kernels use them.
"""

from __future__ import annotations

import numba
import numpy as np
import pytest

import _oracle
from gaussfuse._kernels._dense import BLAS_FROM, cho_solve, cholesky, congruence, matmul


@numba.njit(cache=True)
def _matmul(A, B, C, p, q, r):
    matmul(A, B, C, p, q, r)


@numba.njit(cache=True)
def _congruence(B, P, Y, out, BP, k, n):
    congruence(B, P, Y, out, BP, k, n)


@numba.njit(cache=True)
def _congruence0(B, P, out, BP, k, n):
    congruence(B, P, None, out, BP, k, n)


@numba.njit(cache=True)
def _cholesky(S, L, p):
    return cholesky(S, L, p)


@numba.njit(cache=True)
def _cho_solve(L, X, p, r):
    cho_solve(L, X, p, r)


BIG = BLAS_FROM + 3
SHAPES = [(1, 1, 1), (2, 3, 4), (5, 5, 5), (BLAS_FROM, BLAS_FROM, BLAS_FROM), (BIG, BIG - 2, BIG + 5), (2, BIG * 4, BIG * 3)]


@pytest.mark.parametrize("p, q, r", SHAPES)
def test_matmul_on_leading_blocks(p, q, r):
    rng = np.random.default_rng(p * q * r)
    A, B = rng.standard_normal((p + 1, q + 2)), rng.standard_normal((q + 3, r + 1))
    C = np.full((p + 2, r + 2), 7.0)
    _matmul(A, B, C, p, q, r)
    np.testing.assert_allclose(C[:p, :r], A[:p, :q] @ B[:q, :r], rtol=1e-13, atol=1e-13 * q)
    assert (C[p:] == 7.0).all() and (C[:, r:] == 7.0).all()  # nothing outside the block


@pytest.mark.parametrize("k, n", [(1, 1), (2, 4), (4, 4), (3, BLAS_FROM), (BLAS_FROM, BLAS_FROM), (BIG, BIG + 4)])
def test_congruence_is_the_symmetrised_product(k, n):
    rng = np.random.default_rng(k + 10 * n)
    B = rng.standard_normal((k, n))
    P, Y = _oracle.random_spd(rng, n), _oracle.random_spd(rng, k)
    out, BP = np.empty((k, k)), np.empty((k, n))
    _congruence(B, P, Y, out, BP, k, n)
    X = B @ P @ B.T + Y
    np.testing.assert_allclose(BP, B @ P, rtol=1e-12, atol=1e-12 * np.abs(B @ P).max())
    np.testing.assert_allclose(out, 0.5 * (X + X.T), rtol=1e-12, atol=1e-12 * np.abs(X).max())
    np.testing.assert_array_equal(out, out.T)
    _congruence0(B, P, out, BP, k, n)
    X = B @ P @ B.T
    np.testing.assert_allclose(out, 0.5 * (X + X.T), rtol=1e-12, atol=1e-12 * np.abs(X).max())


@pytest.mark.parametrize("p", [1, 2, 5, BLAS_FROM, BIG])
def test_cholesky_and_solve(p):
    rng = np.random.default_rng(p)
    S = np.zeros((p + 2, p + 2))
    S[:p, :p] = _oracle.random_spd(rng, p)
    L = np.zeros_like(S)
    assert _cholesky(S, L, p)
    np.testing.assert_allclose(np.tril(L[:p, :p]), np.linalg.cholesky(S[:p, :p]), rtol=1e-12, atol=1e-12)
    X = rng.standard_normal((p + 1, 7))
    want = np.linalg.solve(S[:p, :p], X[:p, :5])
    _cho_solve(L, X, p, 5)
    np.testing.assert_allclose(X[:p, :5], want, rtol=1e-9, atol=1e-9 * np.abs(want).max())


@pytest.mark.parametrize("p", [1, 3, BLAS_FROM, BIG])
@pytest.mark.parametrize("bad", ["negative", "zero", "nan"])
def test_cholesky_fails_where_lapack_does(p, bad):
    S = np.eye(p)
    S[p - 1, p - 1] = {"negative": -1.0, "zero": 0.0, "nan": np.nan}[bad]
    assert not _cholesky(S, np.zeros((p, p)), p)
    if bad != "nan":
        with pytest.raises(np.linalg.LinAlgError):
            np.linalg.cholesky(S)
