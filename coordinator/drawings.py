"""Keyframe drawings of the shipped animations (paper 6 and 7.3): "leaf", "story" (Fig. 16), "triangle"
and "history" (7.5.2, Fig. 21). As in coordinator.shapes, parts in the unit square are painted in order;
touching parts differ in colour far beyond the segmentation's tolerance, so each is its own region R_i.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from .shapes import RED, RGB, Inside, Part, circle, paint, polygon, union

SIZE = 256  # default canvas side in pixels

# leaf colours from spring to winter; the branch is a cool dark grey, far from every leaf colour
BRANCH: RGB = (75, 78, 90)
LEAF_GREENS: tuple[RGB, ...] = ((110, 190, 70), (70, 170, 60), (50, 150, 50), (40, 140, 45))
LEAF_FALL: tuple[RGB, ...] = ((150, 175, 50), (220, 190, 45), (215, 135, 40), (160, 90, 40))
HUMAN, STEM, PETAL, FLOWER_CENTRE = (30, 80, 200), (40, 150, 60), RED, (245, 215, 50)
BEE: RGB = (120, 60, 170)  # violet: far from the petals, the centre and the stem
# the History of the Universe (none near the white background)
BANG_CORE, BANG_FIRE, SUN, EARTH, MOON = (250, 215, 40), (230, 70, 30), (245, 165, 30), (40, 100, 220), (140, 140, 150)
LAND, SEA, MICROBE, FISH = (60, 165, 60), (30, 90, 190), (150, 215, 60), (245, 120, 30)
DINOSAUR, PERSON = (80, 140, 50), (215, 60, 120)


def capsule(a: tuple[float, float], b: tuple[float, float], r: float) -> Inside:
    """Points within r of the segment ab: a limb, a stem or a branch."""
    ax, ay = a
    dx, dy = b[0] - ax, b[1] - ay
    length2 = max(dx * dx + dy * dy, 1e-12)

    def inside(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        t = np.clip(((x - ax) * dx + (y - ay) * dy) / length2, 0.0, 1.0)
        return (x - ax - t * dx) ** 2 + (y - ay - t * dy) ** 2 < r * r

    return inside


def ellipse(cx: float, cy: float, a: float, b: float, angle: float = 0.0) -> Inside:
    """An ellipse with semi-axes a (along `angle`, radians, y down) and b."""
    c, s = math.cos(angle), math.sin(angle)

    def inside(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        u, v = (x - cx) * c + (y - cy) * s, -(x - cx) * s + (y - cy) * c
        return (u / a) ** 2 + (v / b) ** 2 < 1.0

    return inside


def leaf(anchor: tuple[float, float], angle: float, length: float, *, bend: float = 0.0, wilt: float = 0.0) -> Inside:
    """A leaf from its stalk at `anchor` along `angle` (radians, y down), asymmetric so its rotation is
    unambiguous; bend curls the midrib, wilt narrows one half of the blade (0: fresh, 1: gone)."""
    c, s = math.cos(angle), math.sin(angle)
    stalk = 0.16  # petiole length, in leaf lengths

    def inside(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        dx, dy = (x - anchor[0]) / length, (y - anchor[1]) / length
        u = dx * c + dy * s - stalk  # along the midrib, blade from 0 to 1
        v = -dx * s + dy * c
        v = v - bend * np.clip(u, 0.0, None) ** 2  # curled midrib
        uc = np.clip(u, 0.0, 1.0)
        half = 0.62 * uc**0.55 * (1.0 - uc) ** 1.1  # half-width of the blade
        half = np.where(v > 0, half * (1.0 - wilt), half)
        blade = (u >= 0) & (u <= 1) & (np.abs(v) < half)
        petiole = (u >= -stalk) & (u < 0.05) & (np.abs(v) < 0.035)
        return blade | petiole

    return inside


# per keyframe: (size, colour, bend, wilt, None on the branch, else the blade centre (x, y) and its turn in degrees)
_LeafFrame = tuple[float, RGB, float, float, "tuple[float, float, float] | None"]
_LEAF_FRAMES: tuple[_LeafFrame, ...] = (
    (0.50, LEAF_GREENS[0], 0.0, 0.0, None),  # spring: a young leaf grows
    (0.66, LEAF_GREENS[1], 0.0, 0.0, None),
    (0.83, LEAF_GREENS[2], 0.0, 0.0, None),
    (1.00, LEAF_GREENS[3], 0.0, 0.0, None),
    (1.00, LEAF_FALL[0], 0.15, 0.05, None),  # fall: it yellows, curls and shrinks
    (0.95, LEAF_FALL[1], 0.30, 0.15, None),
    (0.90, LEAF_FALL[2], 0.45, 0.25, None),
    (0.85, LEAF_FALL[3], 0.55, 0.30, None),
    (0.85, LEAF_FALL[3], 0.55, 0.30, (0.58, 0.48, 40.0)),  # winter: blown off, it falls and turns
    (0.85, LEAF_FALL[3], 0.55, 0.30, (0.62, 0.62, 85.0)),
    (0.85, LEAF_FALL[3], 0.55, 0.30, (0.55, 0.74, 130.0)),
)
_ANCHOR = (0.36, 0.165)  # where the stalk meets the branch
_LEAF_ANGLE = math.radians(50.0)  # the grown leaf hangs down and to the right
_LEAF_LENGTH = 0.55
_BLADE_CENTRE = 0.16 + 0.45  # from the stalk's end to the blade's middle, in leaf lengths


def leaf_frame(k: int, size: int = SIZE) -> np.ndarray:
    """Keyframe k of the leaf animation (0 <= k < 11)."""
    scale, colour, bend, wilt, falling = _LEAF_FRAMES[k]
    length, angle, anchor = _LEAF_LENGTH * scale, _LEAF_ANGLE, _ANCHOR
    if falling is not None:  # turn about the blade's middle, which follows the falling path
        cx, cy, turn = falling
        angle += math.radians(turn)
        reach = _BLADE_CENTRE * length
        anchor = (cx - reach * math.cos(angle), cy - reach * math.sin(angle))
    blade = leaf(anchor, angle, length, bend=bend, wilt=wilt)
    branch = capsule((0.10, 0.185), (0.82, 0.115), 0.017)
    return paint([(blade, colour), (branch, BRANCH)], size)


def walker(x: float, phase: float) -> list[Part]:
    """A walking human at horizontal position x; phase in [-1, 1] swings the legs and arms."""
    head = circle(x, 0.19, 0.065)
    hip, neck, shoulder = (x, 0.55), (x, 0.26), (x, 0.31)
    step, swing = 0.13 * phase, 0.10 * phase
    limbs = [
        capsule(neck, hip, 0.042),
        capsule(hip, (x + step, 0.86), 0.032),
        capsule(hip, (x - step, 0.86), 0.032),
        capsule(shoulder, (x - swing, 0.56), 0.026),
        capsule(shoulder, (x + swing, 0.56), 0.026),
    ]
    return [(union(head, *limbs), HUMAN)]


def heap() -> list[Part]:
    """The human fallen into a heap: a lumpy mound on the ground."""
    ground = 0.86
    lumps = union(circle(0.42, 0.80, 0.11), circle(0.56, 0.77, 0.13), circle(0.70, 0.81, 0.09))
    return [(lambda x, y: lumps(x, y) & (y < ground), HUMAN)]


def flower(bee_angle: float | None) -> list[Part]:
    """A flower and a bee flying round its head at `bee_angle` (radians, y down)."""
    cx, cy = 0.5, 0.40
    stem = union(capsule((cx, 0.88), (cx, cy), 0.022), ellipse(0.59, 0.70, 0.09, 0.035, math.radians(-30)))
    around = np.linspace(0, 2 * math.pi, 6, endpoint=False) + math.pi / 2
    petals = union(*(circle(cx + 0.10 * math.cos(a), cy + 0.10 * math.sin(a), 0.068) for a in around))
    parts: list[Part] = [(stem, STEM), (petals, PETAL), (circle(cx, cy, 0.06), FLOWER_CENTRE)]
    if bee_angle is not None:
        bx, by = cx + 0.33 * math.cos(bee_angle), cy + 0.30 * math.sin(bee_angle)
        parts.append((ellipse(bx, by, 0.045, 0.028, bee_angle + math.pi / 2), BEE))
    return parts


def triangle(angle: float, radius: float) -> list[Part]:
    """An equilateral triangle round the centre with circumradius `radius`, turned by `angle` (radians, y down)."""
    corners = (-math.pi / 2, math.pi / 6, 5 * math.pi / 6)
    return [(polygon([_on_circle(_CENTRE, radius, -(angle + a)) for a in corners]), RED)]


# the History of the Universe (paper 7.5.2): within 0.47 of the centre, inside the round table's rim
_CENTRE = (0.5, 0.5)


def _on_circle(centre: tuple[float, float], radius: float, angle: float) -> tuple[float, float]:
    """The point at `angle` (radians, counter-clockwise as seen: image rows point down) on a circle."""
    return centre[0] + radius * math.cos(angle), centre[1] - radius * math.sin(angle)


def big_bang(burst: float) -> list[Part]:
    """A hot core in a ball of fire (burst 0) that bursts into rays, long and short in turn (burst 1)."""
    fire: list[Inside] = [circle(*_CENTRE, 0.2 - 0.03 * burst)]
    for k in range(8):
        a = math.pi / 8 + k * math.pi / 4
        reach = 0.2 + burst * (0.25 if k % 2 == 0 else 0.13)
        ray = [_on_circle(_CENTRE, 0.12, a - 0.3), _on_circle(_CENTRE, reach, a), _on_circle(_CENTRE, 0.12, a + 0.3)]
        fire.append(polygon(ray))
    return [(union(*fire), BANG_FIRE), (circle(*_CENTRE, 0.09 + 0.01 * burst), BANG_CORE)]


def solar_system(earth_angle: float) -> list[Part]:
    """The Sun, the Earth at `earth_angle` on its orbit and the Moon round the Earth, twice as fast."""
    earth = _on_circle(_CENTRE, 0.314, earth_angle)
    moon = _on_circle(earth, 0.118, 2.0 * earth_angle + math.pi / 2)
    return [(circle(*_CENTRE, 0.135), SUN), (circle(*earth, 0.065), EARTH), (circle(*moon, 0.038), MOON)]


# continents as ellipses (centre, semi-axes, angle) in units of the Earth's radius, about its centre
_CONTINENTS = (((-0.38, -0.28), 0.36, 0.22, 0.35), ((0.34, 0.05), 0.22, 0.42, -0.5), ((-0.12, 0.55), 0.32, 0.16, 0.1))


def _both(a: Inside, b: Inside) -> Inside:
    return lambda x, y: a(x, y) & b(x, y)


def planet_earth(radius: float) -> list[Part]:
    """The Earth seen from close by: ocean and three continents, `radius` of the canvas (a zoom)."""
    cx, cy = _CENTRE
    globe = circle(cx, cy, radius)
    parts: list[Part] = [(globe, EARTH)]
    for (u, v), a, b, angle in _CONTINENTS:
        land = ellipse(cx + u * radius, cy + v * radius, a * radius, b * radius, angle)
        parts.append((_both(land, globe), LAND))
    return parts


def sea(microbe: tuple[float, float], fish: tuple[float, float] | None) -> list[Part]:
    """The sea below a wavy surface, a microbe (a blob with bumps) and, if given, a fish swimming left."""
    cx, cy = _CENTRE

    def water(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        surface = 0.46 + 0.025 * np.sin(6 * math.pi * x)
        return ((x - cx) ** 2 + (y - cy) ** 2 < 0.42**2) & (y > surface)

    mx, my = microbe
    bumps = [circle(mx + 0.1 * math.cos(a), my + 0.068 * math.sin(a), 0.026) for a in (0.4, 1.9, 3.5, 5.0)]
    parts: list[Part] = [(water, SEA), (union(ellipse(mx, my, 0.1, 0.068, 0.3), *bumps), MICROBE)]
    if fish is not None:
        fx, fy = fish
        tail = polygon([(fx + 0.12, fy), (fx + 0.23, fy - 0.08), (fx + 0.23, fy + 0.08)])
        parts.append((union(ellipse(fx, fy, 0.16, 0.08), tail), FISH))
    return parts


def dinosaur(stretch: float) -> list[Part]:
    """A long-necked dinosaur facing right, its head low (stretch 0) or its neck stretched up (1)."""
    base = (0.56, 0.53)
    head = (0.72 - 0.06 * stretch, 0.42 - 0.29 * stretch)
    legs = [capsule((x, 0.6), (x, 0.82), 0.028) for x in (0.30, 0.37, 0.48, 0.55)]
    body = union(
        ellipse(0.42, 0.58, 0.19, 0.1),
        *legs,
        capsule((0.26, 0.58), (0.1, 0.65), 0.03),
        capsule(base, head, 0.032),
        ellipse(head[0] + 0.03, head[1], 0.05, 0.03),
    )
    return [(body, DINOSAUR)]


def person(arms_up: bool) -> list[Part]:
    """A human (thicker than the walker, so its robots stay apart) walking in, or waving both arms."""
    x = 0.4 if not arms_up else 0.5
    hip, neck, shoulder = (x, 0.56), (x, 0.27), (x, 0.32)
    feet = [(x - 0.14, 0.86), (x + 0.14, 0.86)] if not arms_up else [(x - 0.07, 0.86), (x + 0.07, 0.86)]
    hands = [(x - 0.12, 0.56), (x + 0.12, 0.56)] if not arms_up else [(x - 0.18, 0.13), (x + 0.18, 0.13)]
    limbs = (
        [capsule(neck, hip, 0.05)]
        + [capsule(hip, f, 0.038) for f in feet]
        + [capsule(shoulder, h, 0.034) for h in hands]
    )
    return [(union(circle(x, 0.19, 0.07), *limbs), PERSON)]


def history_frames() -> list[list[Part]]:
    """The History of the Universe's keyframes' parts, in play order; the last picture of the big bang, the
    Earth, the sea and the dinosaur is given twice, to be held still (robots reach a keyframe as the next
    begins, eq. 27)."""
    bang, earth = [big_bang(0.0), big_bang(1.0)], [planet_earth(0.22), planet_earth(0.44)]
    life = [sea((0.45, 0.7), None), sea((0.32, 0.72), (0.55, 0.62))]
    dino = [dinosaur(0.0), dinosaur(1.0)]
    orbit = [solar_system(math.radians(45.0 * k)) for k in range(9)]
    return [*bang, bang[-1], *orbit, *earth, earth[-1], *life, life[-1], *dino, dino[-1], person(False), person(True)]


_BEE_ANGLES = (-0.15, -1.6, -3.0)  # the bee flies round the flower head, right to top to left
_ANIMATIONS: dict[str, Callable[[int], list[np.ndarray]]] = {
    "leaf": lambda size: [leaf_frame(k, size) for k in range(len(_LEAF_FRAMES))],
    "story": lambda size: (
        [paint(walker(0.36 + 0.09 * k, p), size) for k, p in enumerate((1.0, 0.15, -1.0))]
        + [paint(heap(), size)]
        + [paint(flower(a), size) for a in _BEE_ANGLES]
    ),
    "triangle": lambda size: [paint(triangle(math.radians(20 * k), 0.16 + 0.035 * k), size) for k in range(7)],
    "history": lambda size: [paint(parts, size) for parts in history_frames()],
}
KEYFRAME_ANIMATIONS = tuple(_ANIMATIONS)


def keyframes(name: str, size: int = SIZE) -> list[np.ndarray]:
    """The keyframes I_1..I_F of animation `name` (one of KEYFRAME_ANIMATIONS), RGB uint8 arrays."""
    if name not in _ANIMATIONS:
        raise ValueError(f"unknown animation {name!r}; choose from {', '.join(KEYFRAME_ANIMATIONS)}")
    return _ANIMATIONS[name](size)
