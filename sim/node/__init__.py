"""The body node: a process that takes the robots' commands and publishes their poses and the clock,
for the simulated world or for real robots. May import sim.bodies and sim.outputs."""
