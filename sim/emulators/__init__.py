"""Emulators of real robots' protocols and of sensors, for tests and demos without hardware."""
