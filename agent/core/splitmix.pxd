from libc.stdint cimport uint64_t


cdef inline uint64_t splitmix64(uint64_t x) noexcept nogil:
    # Steele et al.'s SplitMix64 finaliser: an integer hash (wrapping uint64 arithmetic), shared by
    # the perturbation of preferred velocities (control.pyx) and the board digest (bidding.pyx)
    x = x + <uint64_t>0x9E3779B97F4A7C15
    x = (x ^ (x >> 30)) * <uint64_t>0xBF58476D1CE4E5B9
    x = (x ^ (x >> 27)) * <uint64_t>0x94D049BB133111EB
    return x ^ (x >> 31)
