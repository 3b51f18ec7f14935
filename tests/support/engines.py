"""One scene, one seed, in every engine: the engines' flags, and lock-step runs shared between the tests
that compare them (test_one_controller, test_collision_avoidance, test_range_auction, test_sync_auction)."""

from __future__ import annotations

import numpy as np

ENGINES = {
    "central": ("--engine", "central"),
    "a process per robot": ("--engine", "distributed"),
    # ten a host: every host decodes every other host's frames, so fewer hosts cost less, and the 14
    # robots of swap and story still leave one host short
    "agent hosts": ("--engine", "distributed", "-k", "10"),
}


def engine_run(shared_runs, scene: str, seed: int, engine: str) -> tuple[dict, dict]:
    """A lock-step run of a shipped scene and seed in one engine, shared with the other tests that
    read that run (test_collision_avoidance: fourteen e-pucks swap rows, a process per robot)."""
    return shared_runs.run(scene, "--clock", "lockstep", "--seed", str(seed), *ENGINES[engine])


def picture(tmp_path) -> str:
    """A picture of two shapes (a disk and a bar), drawn here."""
    import cv2

    image = np.full((120, 160, 3), 255, np.uint8)
    cv2.circle(image, (55, 60), 35, (0, 0, 200), -1)
    cv2.rectangle(image, (100, 25), (145, 95), (200, 0, 0), -1)
    path = tmp_path / "picture.png"
    cv2.imwrite(str(path), image)
    return str(path)


PICTURE_FLAGS = ("--robots", "30", "--seed", "2")


def picture_run(shared_runs, tmp_path, engine: str) -> tuple[dict, dict]:
    """A lock-step run of the picture's 30 robots in one engine, shared with test_sync_auction (the
    agent hosts' run is its quiet run)."""
    return shared_runs.run(picture(tmp_path), "--clock", "lockstep", *PICTURE_FLAGS, *ENGINES[engine])


def assert_waited_for_everyone(metrics: dict, name: str = "") -> None:
    """A lock-step run that waited for everything it waits for, so that it is its seed's run and no other: every
    agent answered every tick, none was heard dead, and no wait ran out (what ran out, if one did)."""
    given_up = {k: v for k, v in metrics["lockstep_waits_given_up"].items() if v}
    assert metrics["missed_ticks"] == 0 and not given_up and not metrics["liveliness_lost"], (
        f"{name}: a wait ran out (a loaded machine?): missed ticks {metrics['missed_ticks']}, "
        f"given up {given_up}, heard dead {metrics['liveliness_lost']}"
    )


def assert_same_trajectory(traj: dict, reference: dict, name: str = "") -> None:
    """The same ticks as ``reference`` and, to 1e-9 m, the same positions; else how long each run is and where
    their positions part (the first tick, its robots), so that a failure says where to look."""
    n = min(len(traj["t"]), len(reference["t"]))
    apart = np.abs(traj["pose"][:n, :, :2] - reference["pose"][:n, :, :2]).max(axis=2)  # (tick, robot)
    parted = np.flatnonzero(apart.max(axis=1) > 1e-9)
    where = "nowhere in the ticks both have"
    if len(parted):
        robots = np.flatnonzero(apart[parted[0]] > 1e-9).tolist()
        where = f"from t = {reference['t'][parted[0]]:.1f} s (robots {robots}), by up to {apart.max():.3g} m"
    same_ticks = len(traj["t"]) == len(reference["t"]) and np.array_equal(traj["t"], reference["t"])
    assert same_ticks and not len(parted), (
        f"{name}: {len(traj['t'])} ticks against {len(reference['t'])}; the positions part {where}"
    )
