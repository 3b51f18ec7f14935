"""Fault injection for studies and tests: per message kind, drop probability and added delay.

Faults act where a message is received (as a lossy link would): each receiver loses and delays its own
copies. A plan reads ``state:drop=0.1,delay=0.05,jitter=0.01``, kinds separated by ';'; a kind no process
receives through a faulted inbox (``fault_kinds()``) is refused, as a plan that would inject nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .codec import BY_NAME

# message kinds only the launcher's recorder receives, and its session takes no fault plan
RECORDED_ONLY = ("sim/truth", "sim/contact")


@dataclass(frozen=True)
class FaultSpec:
    drop: float = 0.0  # probability that a message is lost
    delay: float = 0.0  # fixed added delay, seconds
    jitter: float = 0.0  # uniform extra delay in [0, jitter], seconds

    def __post_init__(self) -> None:
        if not 0.0 <= self.drop <= 1.0:
            raise ValueError(f"drop probability must be in [0, 1], not {self.drop}")
        if not (0 <= self.delay < math.inf and 0 <= self.jitter < math.inf):  # NaN fails both
            raise ValueError(f"delay and jitter must be finite seconds >= 0, not {self.delay} and {self.jitter}")

    @property
    def active(self) -> bool:
        return self.drop > 0 or self.delay > 0 or self.jitter > 0


FaultPlan = dict[str, FaultSpec]  # message kind name ('state', 'cmd', ...) -> spec
SETTINGS = ("drop", "delay", "jitter")  # FaultSpec's fields, as a plan names them
SHAPE = "KIND:drop=P,delay=S,jitter=S"
ALIASES = {"loss": "drop", "lost": "drop", "latency": "delay"}  # what a user may call a setting (a study's `loss`)


def fault_kinds() -> list[str]:
    """The message kinds a plan can act on: the codec's names of what the agents and the world receive."""
    return sorted(name for name in BY_NAME if name not in RECORDED_ONLY)


def parse_faults(text: str) -> FaultPlan:
    """Parse 'KIND:drop=P,delay=S,jitter=S[;KIND:...]' into a plan; ValueError with a clear message."""
    plan: FaultPlan = {}
    kinds = fault_kinds()
    for part in filter(None, (p.strip() for p in text.split(";"))):
        kind, sep, body = part.partition(":")
        kind = kind.strip()
        if not sep or not kind:
            raise ValueError(f"fault {part!r}: expected {SHAPE}")
        if kind not in kinds:
            import difflib  # here: a robot's process loads it only to refuse a plan

            close = difflib.get_close_matches(kind, kinds, n=1)
            maybe = f"did you mean {close[0]!r}? " if close else ""
            raise ValueError(f"fault {part!r}: no message kind {kind!r} ({maybe}kinds: {', '.join(kinds)})")
        values: dict[str, float] = {}
        for item in filter(None, (i.strip() for i in body.split(","))):
            name, eq, value = (piece.strip() for piece in item.partition("="))
            _check_setting(part, kind, name, bool(eq))
            if name in values:
                raise ValueError(f"fault {part!r}: {name} given twice")
            try:
                values[name] = float(value)
            except ValueError:
                raise ValueError(f"fault {part!r}: {value!r} is not a number") from None
        if kind in plan:  # a second entry would silently replace the first
            raise ValueError(f"fault {part!r}: kind {kind!r} given twice (put its settings in one entry)")
        plan[kind] = FaultSpec(**values)
    return plan


def _check_setting(part: str, kind: str, name: str, has_value: bool) -> None:
    """A setting of a plan's entry: one of SETTINGS, with a value; else a ValueError naming the settings."""
    if name not in SETTINGS:
        import difflib  # here: a robot's process loads it only to refuse a plan

        close = ALIASES.get(name) or next(iter(difflib.get_close_matches(name, SETTINGS, n=1)), None)
        maybe = f"did you mean {close!r}? " if close else ""
        raise ValueError(
            f"fault {part!r}: no setting {name!r} ({maybe}settings: {', '.join(SETTINGS)}; a plan reads {SHAPE})"
        )
    if not has_value:
        raise ValueError(f"fault {part!r}: {name} needs a value, e.g. {kind}:{name}=0.1 (a plan reads {SHAPE})")


def format_faults(plan: FaultPlan) -> str:
    return ";".join(f"{k}:drop={s.drop},delay={s.delay},jitter={s.jitter}" for k, s in plan.items())
