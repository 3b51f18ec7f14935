"""End-to-end tests: the real `pixelswarm` command and its child processes (agents, routers, emulated
hardware, viewers, browsers), mostly marked slow."""
