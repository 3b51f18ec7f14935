"""Typed signatures of the compiled auction rounds (agent/core/bidding.pyx), for mypy."""

from typing import Any

import numpy as np

NO_OWNER: int

def merge_records(
    price: np.ndarray,
    owner: np.ndarray,
    released: np.ndarray,
    goal: np.ndarray,
    rec_price: np.ndarray,
    robot: np.ndarray,
    rec_released: np.ndarray,
) -> bool: ...
def merge_one(
    price: np.ndarray,
    owner: np.ndarray,
    released: np.ndarray,
    goal: int,
    rec_price: float,
    robot: int,
    rec_released: bool,
) -> bool: ...
def moved_bound(
    made: float, x0: float, y0: float, dx: float, dy: float, hull_x: np.ndarray, hull_y: np.ndarray, lowest: float
) -> float: ...
def board_digest(price: np.ndarray, owner: np.ndarray, released: np.ndarray) -> int: ...
def bid_on_own_boards(
    boards: Any, rows: np.ndarray, slack: np.ndarray, eps: np.ndarray, taken: np.ndarray
) -> np.ndarray: ...
def merge_boards(boards: Any, rows: np.ndarray, told: np.ndarray, words: Any) -> np.ndarray: ...

class Bidders:
    has_penalty: bool
    def __init__(
        self,
        board: Any,
        goals: np.ndarray,
        robot: np.ndarray,
        goal: np.ndarray,
        hull: tuple[np.ndarray, np.ndarray],
        candidates: int,
    ) -> None: ...
    @property
    def candidates(self) -> int: ...
    def set_penalties(self, rows: np.ndarray, goals: np.ndarray, costs: np.ndarray) -> None: ...
    def freeze(self, position: np.ndarray) -> None: ...
    def first_ranking(self) -> int: ...
    def ranking(self) -> tuple[np.ndarray, np.ndarray]: ...
    def contentment(self, slack: float) -> np.ndarray: ...
    def bid(self, eps: float, slack: float) -> int: ...
    def settle_block(self, eps: np.ndarray, slack: np.ndarray, max_rounds: int) -> tuple[int, int, int]: ...

LEAF: int

def goal_tree(
    goals: np.ndarray, leaf: int = ...
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]: ...
