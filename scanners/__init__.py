"""scanners: the rigs. Hardware drivers (stage, display, camera), acquisition, the scan procedure and
the simulated rig (`scanners.sim`). Top layer: may import `calib` and `stereodic`."""
