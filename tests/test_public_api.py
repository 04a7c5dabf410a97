"""The public functions users call (those docs/, the notebooks and the README use) take their data
positionally and every option keyword-only, and say what they take and give in a numpydoc Parameters /
Returns block, as scikit-image does (STYLE.md)."""

import ast
import importlib
import inspect
import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
OURS = ("calib", "scanners", "stereodic")

PUBLIC = [
    # calibration
    "calib.calibration.calibrate_camera",
    "calib.capture.load_capture",
    "calib.evaluate.ray_error_px",
    "calib.evaluate.ErrorStats.of",
    "calib.patterns.fringe_image",
    "calib.patterns.calibration_sequence",
    "calib.pinhole.prvm_from_opencv",
    "calib.pinhole.read_opencv_yaml",
    "calib.prvm_file.load_prvm",
    # virtual camera
    "stereodic.virtual.camera.fit_optical_centre",
    "stereodic.virtual.camera.default_camera",
    "stereodic.virtual.camera.miss_distance",
    "stereodic.virtual.camera.miss_in_pixels",
    "stereodic.virtual.imm.build_imm",
    "stereodic.virtual.imm.apply_imm",
    "stereodic.virtual.prvm.make_virtual",
    "stereodic.virtual.prvm.virtual_rays",
    "stereodic.virtual.prvm.error_vectors",
    "stereodic.virtual.prvm.save_virtual",
    "stereodic.virtual.prvm.load_virtual",
    "stereodic.virtual.undistort.intensity_matrix",
    "stereodic.virtual.undistort.undistort_image",
    "stereodic.virtual.export.pinhole_of",
    "stereodic.virtual.export.export_text",
    # rig
    "stereodic.stereo.rig.build_rig",
    "stereodic.stereo.rig.rig_from_files",
    "stereodic.stereo.rig.save_rig",
    "stereodic.stereo.rig.load_rig",
    "stereodic.stereo.rig.Rig.to_world",
    "stereodic.stereo.register.estimate_registration",
    "stereodic.stereo.rectify.rectify_pair",
    "stereodic.stereo.triangulate.rays_at",
    "stereodic.stereo.triangulate.triangulate",
    "stereodic.stereo.export.export_rig",
    "stereodic.stereo.export.stereo_matrices",
    "stereodic.formats.import_calibration",
    # structured light
    "stereodic.scan.matching.match_rows",
    "stereodic.scan.phase_filter.smooth_phase",
    "stereodic.scan.pipeline.scan_state",
    "stereodic.scan.cloud.make_cloud",
    "stereodic.scan.cloud.write_cloud",
    "stereodic.scan.cloud.poisson_mesh",
    "stereodic.scan.fit.fit_sphere",
    "stereodic.scan.fit.fit_plane",
    "stereodic.scan.fit.trimmed_range",
    # DIC
    "stereodic.dic.grid.make_grid",
    "stereodic.dic.interpolation.BSplineImage.from_image",
    "stereodic.dic.correlate.correlate_points",
    "stereodic.dic.correlate.correlate_pair",
    "stereodic.dic.sequence.correlate_sequence",
    "stereodic.dic.initial_guess.row_search",
    "stereodic.dic3d.stereo.StereoDic",
    "stereodic.dic3d.stereo.StereoDic.run",
    "stereodic.dic3d.refit.reference_geometry",
    # strain
    "stereodic.strain.fit.strain_2d",
    "stereodic.strain.fit.strain_3d",
    "stereodic.strain.fit.StrainFit",
    "stereodic.strain.fit.StrainFit.__call__",
    "stereodic.strain.measures.measure_strain",
    # the simulated rig
    "scanners.sim.calibration.simulate_calibration",
    "scanners.sim.stereo.simulate_stereo",
    "scanners.sim.scan.simulate_scan",
    "scanners.sim.scan.default_scan_rig",
    "scanners.sim.scan.standard_scenes",
    "scanners.sim.scan.load_truth",
    "scanners.sim.scan_scene.surface_from_dict",
    "scanners.sim.lenses.make_lens",
    "scanners.sim.camera.SimCamera",
    "scanners.sim.camera.SimCamera.render",
    "scanners.sim.camera.SimCamera.set_exposure",
    "scanners.sim.pose.DisplayPose.staged",
    "scanners.sim.dic.load_dic_truth",
    # the browser workspace
    "stereodic.workspace.server.start",
]


def resolve(name: str):
    """The object a dotted name refers to: the longest importable module prefix, then attributes."""
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ModuleNotFoundError:
            continue
        for attr in parts[i:]:
            obj = getattr(obj, attr)
        return obj
    raise ModuleNotFoundError(name)


def documented(doc: str, section: str) -> list[str] | None:
    """The names a numpydoc section lists ("a, b : type" or "**kwargs" lines at the section's own
    indentation), or None when the docstring has no such section."""
    lines = doc.splitlines() + [""]
    rule = re.compile(r"-{3,}")
    for i in range(len(lines) - 1):
        if lines[i] == section and rule.fullmatch(lines[i + 1]):
            names = []
            for j in range(i + 2, len(lines) - 1):
                if rule.fullmatch(lines[j + 1]):
                    break                                   # the next section
                if lines[j] and not lines[j][0].isspace():
                    names += [n.strip().lstrip("*") for n in lines[j].split(" : ")[0].split(",")]
            return names
    return None


def problems(obj) -> list[str]:
    """What breaks the rule in one public callable: an option (a parameter with a default) that can be
    passed positionally; a missing Parameters section (or one that leaves out a parameter); a missing
    Returns section (functions; a class documents its constructor's Parameters)."""
    params = [p for p in inspect.signature(obj).parameters.values() if p.name not in ("self", "cls")]
    out = [f"option {p.name!r} can be passed positionally (put it after the *)"
           for p in params if p.default is not p.empty and p.kind is not p.KEYWORD_ONLY]
    doc = inspect.getdoc(obj) or ""
    listed = documented(doc, "Parameters")
    if listed is None:
        if params:
            out.append("the docstring has no Parameters section")
    else:
        out += [f"parameter {p.name!r} is not in the Parameters section" for p in params if p.name not in listed]
    if not inspect.isclass(obj) and documented(doc, "Returns") is None:
        out.append("the docstring has no Returns section")
    return out


@pytest.mark.parametrize("name", PUBLIC)
def test_public_function_takes_data_positionally_and_options_by_keyword(name):
    assert problems(resolve(name)) == [], name


def _positional_option(image, sigma=1.0):
    """Blur an image.

    Parameters
    ----------
    image : (H, W) float
        The image.
    sigma : float
        Pixels.

    Returns
    -------
    out : (H, W) float
        The blurred image.
    """


def _keyword_option(image, *, sigma=1.0):
    pass


_keyword_option.__doc__ = _positional_option.__doc__   # the same function, but for the *


def _undocumented(image, *, sigma=1.0):
    """Blur an image by sigma pixels."""


def _half_documented(image, mask, *, sigma=1.0):
    """Blur an image.

    Parameters
    ----------
    image : (H, W) float
        The image.

    Returns
    -------
    out : (H, W) float
        The blurred image.
    """


def test_checker_catches_a_positional_option_and_a_missing_docstring_block():
    assert problems(_keyword_option) == []
    assert problems(_positional_option) == ["option 'sigma' can be passed positionally (put it after the *)"]
    assert problems(_undocumented) == ["the docstring has no Parameters section",
                                       "the docstring has no Returns section"]
    assert problems(_half_documented) == ["parameter 'mask' is not in the Parameters section",
                                          "parameter 'sigma' is not in the Parameters section"]


# the command line run from Python (the notebooks do): its one argument is the command's words, which
# the console script leaves out (sys.argv); documented, but not a function of data and options
COMMAND_LINE = {"stereodic.cli.main"}


def _user_code() -> dict[str, str]:
    """Python the user is shown: the notebooks' code cells and the docs' python blocks, by place."""
    out = {}
    for nb in sorted((ROOT / "notebooks").glob("*.ipynb")):
        cells = json.loads(nb.read_text())["cells"]
        out.update({f"{nb.name} cell {i}": "".join(c["source"]) for i, c in enumerate(cells)
                    if c["cell_type"] == "code"})
    for md in sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]:
        for k, block in enumerate(re.findall(r"```python\n(.*?)```", md.read_text(), re.S)):
            out[f"{md.name} block {k}"] = block
    return out


def test_every_function_the_docs_and_notebooks_import_is_checked():
    """A function of ours imported in a notebook or a docs example is in PUBLIC (classes are option or
    result records, checked only where listed)."""
    public = set(PUBLIC) | COMMAND_LINE
    missing = []
    for where, code in _user_code().items():
        for node in ast.walk(ast.parse(code)):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in OURS:
                for alias in node.names:
                    obj = getattr(importlib.import_module(node.module), alias.name)
                    if inspect.isfunction(obj) and f"{obj.__module__}.{obj.__qualname__}" not in public:
                        missing.append(f"{where}: {obj.__module__}.{obj.__qualname__}")
    assert missing == []
