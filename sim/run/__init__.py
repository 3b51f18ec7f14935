"""One run's orchestration: the launcher (router, coordinator, world and agent processes, recording)
and the agents of a run going elsewhere. May import sim.node, sim.central, sim.outputs, sim.bodies."""
