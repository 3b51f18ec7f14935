"""The paper's robot, the e-puck (Table 1), in SI units: the body every package assumes unless a scene
says otherwise. It lives in transport because every other package may import transport (import-linter).
"""

RADIUS = 0.045  # r_A = d_A / 2 (Table 1: d_A = 0.09 m)
V_MAX = 0.13  # maximum linear speed, m/s
OMEGA_MAX = 4.96  # maximum angular speed, rad/s
WHEEL_BASE = 0.0525  # l_w, distance between the wheels, m
