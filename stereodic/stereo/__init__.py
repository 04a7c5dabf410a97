"""Two cameras' rays -> the rectified virtual stereo pair: the rig (`rig`), rectifying images
(`rectify`), triangulation (`triangulate`), registering a camera to a rig (`register`) and the rig's
export to other programs (`export`)."""
