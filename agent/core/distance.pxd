from libc.math cimport INFINITY


cdef inline int against(double d2, double r) noexcept nogil:
    # sqrt(d2) (d2 a squared distance) against a bound r: -1 below it, 1 above it where the squares tell
    # beyond any rounding of theirs or of hypot's; 0 where they cannot (near the bound, r too small or too
    # large to square, NaN): hypot decides. Most distances are far from their bound and skip the slow root
    cdef double r2 = r * r
    if not (1e-200 <= r2 < INFINITY):
        return 0
    if d2 <= r2 * (1.0 - 1e-9):
        return -1
    if d2 >= r2 * (1.0 + 1e-9):
        return 1
    return 0
