"""`stereodic demo`: the end-to-end run on the built-in simulated rig, no hardware needed."""

from __future__ import annotations


from stereodic.cli.common import add_output

DESCRIPTION = """\
The whole toolkit on the built-in simulated rig, no hardware needed: six steps, each a real stereodic
command printed before it runs (repeat any of them by hand), each followed by its error against the
simulator's truth where there is one.
  1. calibration: simulate a calibration bench (a free-form lens, 640x512), calibrate its per-pixel
     rays, draw the ray error against the truth (calibration/, cam0.npz, report/)
  2. virtual camera: undistort a frame, export the virtual pinhole model for OpenCV (undistorted/,
     cam0_pinhole.yaml)
  3. stereo: calibrate a stereo pair (480x384), build the rectified virtual rig, export it for OpenCV
     (stereo/, stereo_cam0.npz, stereo_cam1.npz, rig.npz, rig_opencv.yaml)
  4. scanner: fringe-projection scan of a sphere to a point cloud, its fitted diameter (scan/, sphere.ply)
  5. 2D DIC: a speckle image moved by a known sub-pixel shift (dic/)
  6. stereo 3D-DIC: rectify a speckled plate's image pair (the row alignment in rectified/overlay.png),
     then its shape, displacement and strain in translation, rotation, 1 % tension and bulge (dic3d/,
     rectified/, dic3d_result/)
About 2-3 minutes on two cores; the first run after an install also compiles the numba kernels."""


def register(sub):
    p = sub.add_parser("demo", help="end-to-end run on the built-in simulated rig, no hardware",
                       description=DESCRIPTION)
    add_output(p, kind="dir", default="demo-out", metavar="DIR", help="output folder (default: demo-out)")
    p.set_defaults(func=run)


def run(args) -> int:
    from stereodic.demo import run_demo
    return run_demo(args.output)
