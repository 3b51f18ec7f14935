"""A restarted agent's first command may reach the world before the news that its agent is alive
(two zenoh subscriptions, no order between them). The world holds it for the tick and applies it
once the agent is heard alive: dropped, the world would wait out its deadline for a command the
agent already sent (a missed tick, 2 s in lock-step, after every restart)."""

from __future__ import annotations

from coordinator.scene import load_scene
from sim.node.world import world_node
from tests.conftest import wait_for
from transport.bus import Bus
from transport.codec import Command, Commands
from transport.session import client_of, loopback_router


def test_a_command_that_overtakes_its_agents_liveliness_is_applied_once_the_agent_is_heard():
    scene = load_scene("swap", robots=2, seed=0, clock="lockstep", duration=1.0)
    router = loopback_router()
    with Bus(router, name="world") as world_bus, Bus(client_of(router), name="agent") as agent_bus:
        node = world_node(world_bus, scene, deadline=0.3, startup_timeout=10.0)
        node.update_liveness()
        assert not node.live.any()
        agent_bus.publish(agent_bus.keys.cmd(0), Commands.one(Command(0, 0, 0.0, Command.HOLONOMIC, 0.0, 0.0, 0, 0, 0)))
        assert wait_for(lambda: bool(node.early) or (node.take_commands() or bool(node.early)), timeout=10)
        assert node.last_cmd_tick[0] == -1  # not alive yet: not applied
        agent_bus.declare_alive("agent", 0)
        assert wait_for(lambda: node.take_commands() or node.last_cmd_tick[0] == 0, timeout=10)
        assert node.live[0] and not node.early
        node.step_tick()  # a command held for a tick is not applied at a later one
        assert node.tick == 1 and not node.early
