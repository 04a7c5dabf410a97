"""scanners: the rigs. Hardware drivers (stage, display, camera), acquisition, the alignment aid's live
loop and the simulated rig (`scanners.sim`). Imports `calib` only (tests/test_layering.py)."""
