"""What the coordinator and the recorder use of transport.bus.Bus, in process, without zenoh."""

from __future__ import annotations

from transport.keys import Keys


class Inbox:
    def __init__(self) -> None:
        self.items: list = []

    def drain(self) -> list:
        out, self.items = self.items, []
        return out


class Bus:
    """What the coordinator uses of transport.bus.Bus, without zenoh."""

    def __init__(self) -> None:
        self.keys = Keys()
        self.clock, self.alive, self.events, self.published = Inbox(), Inbox(), Inbox(), []

    def subscribe(self, key: str, expected=None, only=None) -> Inbox:
        return {self.keys.clock: self.clock, self.keys.agents_events: self.events}.get(key, Inbox())

    def watch_alive(self, role=None) -> Inbox:
        return self.alive

    def serve(self, key: str, answer) -> None:
        pass

    def publish(self, key: str, msg) -> None:
        self.published.append(msg)

    def renew_if_due(self) -> bool:
        return False  # no link to lose


class RecorderBus(Bus):
    """The coordinator tests' bus without zenoh, with the recorder's raw inbox."""

    def __init__(self) -> None:
        super().__init__()
        self.raw = Inbox()

    def subscribe_raw(self, key: str) -> Inbox:
        return self.raw
