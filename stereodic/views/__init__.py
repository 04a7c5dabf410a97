"""Several views of one object: registration and merging of scans (`stereodic.views.merge`)."""
