"""What every pose source hands out: each robot's newest pose, when it was measured and how old it is."""

from typing import NamedTuple


class PoseSample(NamedTuple):
    x: float  # m
    y: float  # m
    theta: float  # rad
    stamp: float  # s, when it was measured, on the source's clock (a message header, a camera frame)
    age: float  # s since it reached this process (this machine's clock; the stamp's clock may differ)
