"""Stereo 3D digital image correlation on the rectified virtual pair (`stereodic dic`).

Modules, one job each: `dataset` (the states of a `kind: dic` capture, checked, rectified), `stereo`
(the pipeline: stereo, temporal and cross matching, triangulation, displacement, strain), `output`
(CSV, NPZ, PNG maps), `vtk` (ParaView PolyData files).
"""
