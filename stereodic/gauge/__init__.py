"""The materials test from start to finish: gauges over time on a saved DIC result, in the rig's or the
specimen's frame, joined to a testing machine's load.

- `frame`: the specimen's frame (best-fit plane of the reference shape) and each state's rigid motion;
- `result`: a saved `dic` or `dic2d` result read state by state in the chosen frame (`open_gauge_result`);
- `gauges`: virtual extensometers, points, areas and lines at positions in the original left reference
  image (`Gauges`, `measure_gauges`, `parse_gauge_file`);
- `load`: a testing machine's CSV joined to the states, stress and stress-strain (`read_load`,
  `join_load`, `stress`);
- `plots`: their PNG pictures.
"""
