"""The structured-light scan: the pipeline of one scan (`pipeline`: decode, rectify, filter, match,
triangulate), 1-D phase matching along rectified rows (`matching`), phase-map filtering
(`phase_filter`), Open3D clouds and meshes (`cloud`), shape fits (`fit`) and several views of one
object registered and merged (`views`)."""
