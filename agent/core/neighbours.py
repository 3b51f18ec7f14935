"""SplitMix64 for the auction's board digest (agent.core.bidder), until it takes agent.core.control's."""

from __future__ import annotations

from .control import splitmix64

__all__ = ["splitmix64"]
