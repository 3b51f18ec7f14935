"""Tests of components together: real Zenoh sessions or sockets on loopback, the central engine or the
coordinator in process; no full `pixelswarm run`."""
