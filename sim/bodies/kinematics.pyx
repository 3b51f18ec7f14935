"""How the simulated bodies move (sim.bodies.world), compiled: the command each robot realises under
actuation noise, and the exact arc it then drives. The world calls it for every robot at every
step, so it is the simulator's hot loop; the contact detection is sim.bodies.contacts.

- holonomic: the realised velocity is c + noise_rel |c| n + noise_abs n' (n' only when the command
  is not zero: idle motors do not creep), its norm clipped to v_max; it turns at no rate.
- differential drive: each wheel's linear speed c (1 + noise_rel n) + noise_abs n', clipped to
  +-v_max; v = (vl + vr) / 2 and omega = (vr - vl) / wheel_base, clipped to +-omega_max.

A robot at constant (speed, heading, omega) for t seconds moves along the chord of its arc: length
speed t sinc(omega t / 2), direction heading + omega t / 2 (exact for every omega, 0 included).
"""

# cython: language_level=3

from libc.math cimport cos, isfinite, sin, sqrt

import numpy as np


cdef class Bodies:
    """Per robot (N,): the speed limit, whether it drives differentially, its wheel base and turn
    rate limit; for all: the actuation noise, relative (per unit of command) and absolute (m/s)."""

    cdef const double[::1] v_max
    cdef const unsigned char[::1] diffdrive
    cdef const double[::1] wheel_base
    cdef const double[::1] omega_max
    cdef double noise_rel, noise_abs
    cdef readonly Py_ssize_t n

    def __init__(self, v_max, diffdrive, wheel_base, omega_max, double noise_rel, double noise_abs):
        self.v_max = np.ascontiguousarray(v_max, dtype=float)
        self.diffdrive = np.ascontiguousarray(diffdrive, dtype=bool).view(np.uint8)
        self.wheel_base = np.ascontiguousarray(wheel_base, dtype=float)
        self.omega_max = np.ascontiguousarray(omega_max, dtype=float)
        self.n = self.v_max.shape[0]
        if not self.diffdrive.shape[0] == self.wheel_base.shape[0] == self.omega_max.shape[0] == self.n:
            raise ValueError("Bodies: v_max, diffdrive, wheel_base and omega_max need one row per robot")
        self.noise_rel, self.noise_abs = noise_rel, noise_abs


def limit(Bodies bodies, commands):
    """The commands (N, 2) as the bodies take them: a wheel speed clipped to +-v_max, a holonomic
    velocity's norm to v_max. Returns (clipped (N, 2), the first robot whose command is not finite,
    or -1)."""
    clipped_array = np.array(commands, dtype=float, order="C")
    cdef Py_ssize_t n = bodies.n, i
    if clipped_array.shape != (n, 2):
        raise ValueError(f"commands must have shape ({n}, 2), not {clipped_array.shape}")
    cdef double[:, ::1] c = clipped_array
    cdef double vmax, norm
    for i in range(n):
        if not (isfinite(c[i, 0]) and isfinite(c[i, 1])):
            return clipped_array, i
    with nogil:
        for i in range(n):
            vmax = bodies.v_max[i]
            if bodies.diffdrive[i]:
                c[i, 0] = min(max(c[i, 0], -vmax), vmax)
                c[i, 1] = min(max(c[i, 1], -vmax), vmax)
            else:
                norm = sqrt(c[i, 0] * c[i, 0] + c[i, 1] * c[i, 1])
                if norm > vmax:
                    c[i, 0] = c[i, 0] * vmax / norm
                    c[i, 1] = c[i, 1] * vmax / norm
    return clipped_array, -1


def actuate(Bodies bodies, const double[:, ::1] command, const double[:, ::1] noise, const double[::1] theta):
    """Each robot's realised motion (N, 4) from its command (N, 2), its noise draw (N, 4) and its
    heading theta (N,): speed, the direction of motion (a unit vector) and the turn rate."""
    cdef Py_ssize_t n = bodies.n, i
    if command.shape[0] != n or noise.shape[0] != n or theta.shape[0] != n or command.shape[1] != 2 or noise.shape[1] != 4:
        raise ValueError(f"actuate: command (N, 2), noise (N, 4) and theta (N,) for N = {n} robots")
    motion_array = np.zeros((n, 4))
    cdef double[:, ::1] motion = motion_array
    cdef double c0, c1, v0, v1, norm, vmax, wmax, creep
    cdef double rel = bodies.noise_rel
    with nogil:
        for i in range(n):
            c0, c1, vmax = command[i, 0], command[i, 1], bodies.v_max[i]
            creep = bodies.noise_abs if (c0 != 0.0 or c1 != 0.0) else 0.0
            if bodies.diffdrive[i]:
                v0 = c0 * (1.0 + rel * noise[i, 0]) + creep * noise[i, 2]
                v1 = c1 * (1.0 + rel * noise[i, 1]) + creep * noise[i, 3]
                v0 = min(max(v0, -vmax), vmax)
                v1 = min(max(v1, -vmax), vmax)
                wmax = bodies.omega_max[i]
                motion[i, 0] = 0.5 * (v0 + v1)
                motion[i, 1], motion[i, 2] = cos(theta[i]), sin(theta[i])
                motion[i, 3] = min(max((v1 - v0) / bodies.wheel_base[i], -wmax), wmax)
            else:
                norm = sqrt(c0 * c0 + c1 * c1)
                v0 = c0 + rel * norm * noise[i, 0] + creep * noise[i, 2]
                v1 = c1 + rel * norm * noise[i, 1] + creep * noise[i, 3]
                norm = sqrt(v0 * v0 + v1 * v1)
                if norm > 0.0:
                    motion[i, 0] = vmax if norm > vmax else norm
                    motion[i, 1], motion[i, 2] = v0 / norm, v1 / norm
                else:
                    motion[i, 1] = 1.0
    return motion_array


def drive(const double[:, ::1] motion, double since, const double[::1] t, const double[:, ::1] start,
          double[:, :, ::1] out):
    """out[r, i] = start[i] + robot i's displacement in t[r] seconds (t >= 0) at its constant motion
    (N, 4: speed, direction, turn rate) from where it has turned for ``since`` seconds: the chord of
    its arc. out is (len(t), N, 2)."""
    cdef Py_ssize_t n = motion.shape[0], rows = t.shape[0], i, r
    if motion.shape[1] != 4 or start.shape[0] != n or out.shape[1] != n or out.shape[0] != rows:
        raise ValueError("drive: motion (N, 4), start (N, 2), out (len(t), N, 2)")
    cdef double ux, uy, omega, half, chord, c, s
    with nogil:
        for i in range(n):
            ux, uy, omega = motion[i, 1], motion[i, 2], motion[i, 3]
            if omega == 0.0:  # a straight line
                for r in range(rows):
                    chord = motion[i, 0] * t[r]
                    out[r, i, 0] = start[i, 0] + chord * ux
                    out[r, i, 1] = start[i, 1] + chord * uy
            else:
                for r in range(rows):
                    half = 0.5 * omega * t[r]
                    chord = motion[i, 0] * t[r] * (sin(half) / half if half != 0.0 else 1.0)
                    c, s = cos(omega * since + half), sin(omega * since + half)
                    out[r, i, 0] = start[i, 0] + chord * (ux * c - uy * s)
                    out[r, i, 1] = start[i, 1] + chord * (ux * s + uy * c)
