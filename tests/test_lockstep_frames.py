"""A lock-step host steps a tick's poses frame whole (agent.runtime.AgentHost.run), over a real zenoh
router on loopback. The inbox hands a frame's records over one by one; on a loaded machine the
thread handing them over can stall between two records. A real-time host then steps the robots it
has (a command late by a batch is worse than none), but a lock-step host that did so froze its
auction block on the other robots' poses of the tick before: the run was no longer the run of its
seed. Here the records of each frame arrive 0.2 s apart, four times the real-time batch wait."""

from __future__ import annotations

import threading
import time

import numpy as np

from agent.core.params import RobotParams
from agent.runtime import AgentHost, HostConfig
from transport.bus import Bus
from transport.codec import BEFORE_START, Pose, Poses, Tick
from transport.session import client_of, loopback_router, open_session

DT = 0.1
WHERE = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])  # two robots of one host, apart


def test_a_lockstep_host_steps_every_robot_of_a_tick_at_once_when_the_frame_comes_in_pieces() -> None:
    router = loopback_router()
    session = open_session(router)
    started = threading.Event()
    try:
        with Bus(client_of(router), "frames") as world, Bus(client_of(router), "frames") as agent_bus:
            commands = world.commands_inbox()
            config = HostConfig(robots=[0, 1], params=RobotParams(kinematics="holonomic"), lockstep=True, frames=True)
            host = AgentHost(agent_bus, config)
            deliver = host.pose_inbox._deliver

            def in_pieces(key: str, msgs: list) -> None:  # a stalled hand-over between two records
                for m in msgs:
                    deliver(key, [m])
                    time.sleep(0.2)

            host.pose_inbox._deliver = in_pieces  # type: ignore[method-assign]
            batches: list[list[int]] = []
            step_tick = host._step_tick

            def counted(poses: list[Pose]) -> None:
                batches.append([q.robot for q in poses])
                step_tick(poses)

            host._step_tick = counted  # type: ignore[method-assign]

            def run() -> None:
                if host.start(timeout=20.0):
                    started.set()
                    host.run()

            thread = threading.Thread(target=run, daemon=True)
            thread.start()
            end = time.monotonic() + 20.0
            while not started.is_set() and time.monotonic() < end:
                world.publish_poses(BEFORE_START, 0.0, np.array([0, 1]), WHERE, frame=False)
                time.sleep(0.2)
            assert started.is_set(), "the host did not start"
            for k in range(3):
                world.publish(world.keys.clock, Tick(k, k * DT, DT, 0))
                world.publish(world.keys.poses, Poses.of(k, k * DT, [Pose(r, k, k * DT, *WHERE[r]) for r in (0, 1)]))
                heard: set[int] = set()
                deadline = time.monotonic() + 20.0
                while heard != {0, 1} and time.monotonic() < deadline:
                    got = commands.get(timeout=0.1)
                    if got is not None and got[1].tick == k:
                        heard.add(got[1].robot)
                assert heard == {0, 1}, f"tick {k}: commands of {sorted(heard)}"
            host.running = False
            thread.join(timeout=5.0)
            assert not thread.is_alive()
            assert batches == [[0, 1]] * 3, f"the ticks were stepped in batches {batches}"
    finally:
        session.close()
