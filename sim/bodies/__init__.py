"""The simulated bodies: robots' kinematics, arena, obstacles, contacts, scripted movers and the
simulated tracker. May import agent, coordinator and transport only."""
