"""Comparisons for the Python tests that cannot pass on nothing: both sides
must hold values, all finite, before they are compared."""
import numpy as np


def _real(name, a):
    a = np.asarray(a)
    assert a.size > 0, f"{name} is empty"
    if a.dtype.kind in "fiu":
        assert np.isfinite(a).all(), f"{name} has non-finite values: {a.ravel()[:8]}"
    return a


def assert_same(got, want):
    """Equal to the last bit, both sides real."""
    np.testing.assert_array_equal(_real("got", got), _real("want", want))


def assert_close(got, want, **tolerance):
    """Within np.testing.assert_allclose's tolerance, both sides real."""
    np.testing.assert_allclose(_real("got", got), _real("want", want), **tolerance)
