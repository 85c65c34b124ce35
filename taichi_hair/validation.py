"""Type tests shared by the input checks: a real number is any real of any numeric type
(Python int or float, numpy integer or floating scalar: np.float32(1e-3) is a valid dt), never a bool."""

import numbers


def is_real(value) -> bool:
    """True for a real number of any numeric type (not bool); finiteness is the caller's check."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def is_integer(value) -> bool:
    """True for an integer of any integer type (int, numpy integers), not bool."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)
