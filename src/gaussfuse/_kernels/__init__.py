"""Compiled kernels: the only place numba is imported.

Each module implements, for the methods that name it in
:data:`gaussfuse.inference.METHODS`, the same equations as the readable
path (:mod:`gaussfuse.kalman`), compiled with numba and cached on disk
(through :func:`._jit.jit`, which compiles in memory when nothing can be
cached):

* ``filter(method, model, prior, zs, us, options, keep) -> FilterResult``
* ``smooth(method, model, prior, zs, us, options) -> SmoothResult``

with validated measurements ``zs`` of shape (N, T, m), controls ``us`` of
shape (N, T, p) or None, and results that carry the leading N axis.
Importing this package does not import numba; importing a module in it does.
"""
