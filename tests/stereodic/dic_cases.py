"""Simulated stereo DIC datasets for the tests, with the rig `stereodic simulate dic` adds: the rectified
pair of the simulator's true camera models (truth_cam0.npz, truth_cam1.npz), built by `stereodic.stereo.rig`."""

from scanners.sim.dic import simulate_dic
from stereodic.stereo.rig import rig_from_files, save_rig


def simulate_dic_with_rig(root, states, **options):
    """`scanners.sim.dic.simulate_dic(root, states, **options)`, then root/rig.npz; returns the dataset."""
    cap = simulate_dic(root, states, **options)
    save_rig(root / "rig.npz", rig_from_files(root / "truth_cam0.npz", root / "truth_cam1.npz"))
    return cap
