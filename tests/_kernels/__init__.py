"""Tests of the compiled kernels (a package, so their basenames may repeat those elsewhere)."""
