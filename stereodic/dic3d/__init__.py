"""Stereo 3D digital image correlation on the rectified virtual pair (`stereodic dic`).

Modules, one job each: `dataset` (the states of a `kind: dic` capture, checked, rectified), `stereo`
(the pipeline: stereo, temporal and cross matching, triangulation, displacement, strain), `output`
(CSV, NPZ, PNG maps), `vtk` (ParaView PolyData files), `epipolar` (the rig's health), `refit` (a rig
whose calibration no longer fits: the rows' offsets, the right camera re-oriented), `diagnose` (why a
state measured little).
"""
