"""Export of a rig for legacy software: OpenCV stereo YAML, DICe XML, COLMAP, JSON."""

import json
import xml.etree.ElementTree as ET

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from stereodic.cli import main
from stereodic.stereo.rig import save_rig
from stereodic.stereo.triangulate import triangulate
from tests.stereodic.rig_cases import pair


def _rig_file(tmp_path):
    *_, rig = pair("brown", "noncentral")
    save_rig(tmp_path / "rig.npz", rig)
    return rig, str(tmp_path / "rig.npz")


def _read_yaml(path):
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    out = {k: fs.getNode(k).mat() for k in ("M1", "D1", "M2", "D2", "R", "T", "R1", "R2", "P1", "P2", "Q",
                                             "R_wcs", "T_wcs")}
    out["size"] = (int(fs.getNode("image_width").real()), int(fs.getNode("image_height").real()))
    fs.release()
    return out


def test_opencv_triangulation_reproduces_ours(tmp_path):
    """cv2.triangulatePoints with the exported P1, P2 gives our plane points within 1e-6 x the working
    distance, and reprojectImageTo3D's Q our pinhole triangulation off the plane."""
    rig, path = _rig_file(tmp_path)
    assert main(["export", path, "--format", "opencv", "-o", str(tmp_path / "stereo.yml")]) == 0
    m = _read_yaml(tmp_path / "stereo.yml")
    assert m["size"] == (rig.sensor.width, rig.sensor.height)
    assert not m["D1"].any() and not m["D2"].any()
    assert np.allclose(m["R"], np.eye(3), atol=1e-12) and m["T"][0, 0] < 0
    rng = np.random.default_rng(1)
    x, r = rng.uniform(0, rig.sensor.width - 1, 500), rng.uniform(0, rig.sensor.height - 1, 500)
    ours = triangulate(rig, x, x, r, corrected=False).points
    h = cv2.triangulatePoints(m["P1"], m["P2"], np.stack([x, r]), np.stack([x, r]))
    cam1 = (h[:3] / h[3]).T
    wcs = (cam1 - m["T_wcs"].ravel()) @ m["R_wcs"]          # R_wcs^T (x - T_wcs)
    assert np.abs(wcs - ours).max() <= 1e-6 * rig.working_distance_mm
    # off the plane: Q on the disparity xL - xR gives the pinhole triangulation
    xr = x - rng.uniform(-40, 40, 500)
    ours = triangulate(rig, x, xr, r, corrected=False).points
    q = np.column_stack([x, r, x - xr, np.ones_like(x)]) @ m["Q"].T
    wcs = (q[:, :3] / q[:, 3:] - m["T_wcs"].ravel()) @ m["R_wcs"]
    assert np.abs(wcs - ours).max() <= 1e-6 * rig.working_distance_mm


def test_dice_colmap_json(tmp_path):
    rig, path = _rig_file(tmp_path)
    assert main(["export", path, "--format", "dice", "-o", str(tmp_path / "cal.xml")]) == 0
    root = ET.parse(tmp_path / "cal.xml").getroot()
    params = {p.get("name"): p.get("value") for p in root.findall("Parameter")}
    assert params["xml_file_format"] == "DICe_xml_camera_system_file"
    cams = {c.get("name"): c for c in root.findall("ParameterList")}
    assert set(cams) == {"CAMERA 0", "CAMERA 1"}
    for side, name in (("left", "CAMERA 0"), ("right", "CAMERA 1")):
        c = {p.get("name"): p.get("value") for p in cams[name].findall("Parameter")}
        rows = {p.get("name"): p.get("value") for p in cams[name].find("ParameterList").findall("Parameter")}
        rot = np.array([[float(v) for v in rows[f"ROW {j}"].strip("{} ").split(",")] for j in range(3)])
        t = np.array([float(c[k]) for k in ("TX", "TY", "TZ")])
        centre = rig.camera(side).centre
        assert np.allclose(-rot.T @ t, centre, atol=1e-9)
        # the camera projects the plane point of virtual pixel (100, 50) onto (100, 50)
        p = rot @ rig.sensor.points(np.array(100.0), np.array(50.0)) + t
        uv = [float(c["FX"]) * p[0] / p[2] + float(c["CX"]), float(c["FY"]) * p[1] / p[2] + float(c["CY"])]
        assert np.allclose(uv, [100, 50], atol=1e-9)
        assert c["LENS_DISTORTION_MODEL"] == "NO_LENS_DISTORTION"
        assert c["IMAGE_HEIGHT_WIDTH"] == f"{{ {rig.sensor.height}, {rig.sensor.width} }}"

    assert main(["export", path, "--format", "colmap", "-o", str(tmp_path / "colmap")]) == 0
    cams_txt = [ln.split() for ln in (tmp_path / "colmap" / "cameras.txt").read_text().splitlines()
                if not ln.startswith("#")]
    imgs = [ln.split() for ln in (tmp_path / "colmap" / "images.txt").read_text().splitlines()
            if ln and not ln.startswith("#")]
    assert [c[1] for c in cams_txt] == ["PINHOLE", "PINHOLE"] and [i[9] for i in imgs] == ["left.png", "right.png"]
    for side, img in zip(("left", "right"), imgs):
        qw, qx, qy, qz, tx, ty, tz = map(float, img[1:8])
        rot = Rotation.from_quat([qx, qy, qz, qw]).as_matrix()
        assert np.allclose(-rot.T @ [tx, ty, tz], rig.camera(side).centre, atol=1e-9)

    assert main(["export", path, "--format", "json", "-o", str(tmp_path / "rig.json")]) == 0
    data = json.loads((tmp_path / "rig.json").read_text())
    assert [c["name"] for c in data["cameras"]] == ["left", "right"]
    assert np.allclose(data["stereo"]["P2"], _read_yaml_p2(tmp_path, path))


def _read_yaml_p2(tmp_path, path):
    assert main(["export", path, "--format", "opencv", "-o", str(tmp_path / "s.yml")]) == 0
    return _read_yaml(tmp_path / "s.yml")["P2"]
