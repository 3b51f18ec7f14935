"""Real bodies and real pose sources: backends that speak a robot's own protocol, the overhead-camera
tracker, motion capture and the safety watchdog. Imports only transport."""
