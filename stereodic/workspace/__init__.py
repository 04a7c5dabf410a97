"""The browser workspace of `stereodic view` (docs/workspace.md): a Dash application served on this
machine to set a DIC run up (the region drawn on the original image, the predicted noise, the run
followed), look at results state by state with gauges, and see calibrations, rigs and scans.

- `access`: the token and served-path rules; `server`: the web server and its routes;
- `app`: what a path holds and the page for it; `dic_view`, `setup_view`, `other_views`: the pages;
- `results`: a DIC result read state by state for the pages; `region`: the region of interest, drawn in
  the original image, as `stereodic dic`'s rectified mask.
"""
