"""Virtual camera files, the EVM, and the exports (OpenCV YAML, COLMAP, JSON)."""

import json

import numpy as np

from calib.pinhole import read_opencv_yaml
from scanners.sim.lenses import make_lens
from stereodic.cli import main
from stereodic.virtual.export import export_text, pinhole_of
from stereodic.virtual.sampling import bilinear
from stereodic.virtual.camera import VirtualCamera, default_camera, fit_optical_centre
from stereodic.virtual.prvm import load_virtual, make_virtual, save_virtual
from virtual_cases import opencv_camera

SMALL = dict(width=160, height=120, pixel_mm=0.0053 * 8)


def test_evm_is_zero_for_a_central_lens_and_restores_true_rays_otherwise():
    central = make_virtual((p := make_lens("brown", seed=5, **SMALL).true_prvm()), default_camera(p))
    assert np.nanmax(np.abs(central.evm)) < 1e-5  # interpolating directions between pixels: ~1e-6
    lens = make_lens("noncentral", seed=5, **SMALL)
    prvm = lens.true_prvm()
    setup = make_virtual(prvm, default_camera(prvm))
    assert np.nanmax(np.linalg.norm(setup.evm, axis=-1)) > 1e-4
    # modelled + EVM = the model-less ray = the true ray at the IMM's real position (a bilinear blend)
    restored = setup.prvm.direction + setup.evm
    _, true_d = lens.rays(setup.imm.map_x.astype(float), setup.imm.map_y.astype(float))
    assert np.abs(restored - true_d).max() < 1e-5
    # every virtual ray goes through its virtual pixel on the sensor plane
    uv = setup.camera.sensor.intersect(setup.prvm.origin, setup.prvm.direction)
    v, u = np.mgrid[0:120, 0:160]
    assert np.abs(uv[..., 0] - u).max() < 1e-9 and np.abs(uv[..., 1] - v).max() < 1e-9
    centre, _ = fit_optical_centre(prvm)
    to_centre = np.cross(setup.prvm.origin - centre, setup.prvm.direction)
    assert np.abs(to_centre).max() < 1e-9  # the modelled rays all pass through the fitted centre


def test_virtual_file_round_trip(tmp_path):
    prvm = opencv_camera()[-1]
    setup = make_virtual(prvm, default_camera(prvm, model="modelless"))
    save_virtual(tmp_path / "v.npz", setup)
    back = load_virtual(tmp_path / "v.npz")
    assert back.camera.to_dict() == setup.camera.to_dict()
    assert np.array_equal(back.imm.map_x, setup.imm.map_x) and np.array_equal(back.imm.valid, setup.imm.valid)
    assert np.array_equal(back.prvm.direction, setup.prvm.direction)
    assert np.nanmax(np.abs(back.evm)) == 0  # model-less: no error
    assert np.allclose(bilinear(prvm.direction, back.imm.map_x, back.imm.map_y), back.prvm.direction)


def test_exports_carry_the_same_pinhole(tmp_path, capsys):
    prvm = opencv_camera()[-1]
    prvm.save(tmp_path / "cam.npz")
    cam = default_camera(prvm)
    p = pinhole_of(cam)
    for fmt in ("opencv", "colmap", "json"):
        assert main(["export", str(tmp_path / "cam.npz"), "--format", fmt, "-o", str(tmp_path / fmt)]) == 0
        assert capsys.readouterr().out.startswith(f"wrote {tmp_path / fmt}: {fmt} pinhole camera")
    y = read_opencv_yaml(tmp_path / "opencv")
    assert np.allclose(y.K, p.K) and np.array_equal(y.dist, np.zeros(5)) and np.allclose(y.R, p.R)
    assert np.allclose(y.centre, cam.centre)
    line = (tmp_path / "colmap").read_text().strip().splitlines()[-1].split()
    assert line[:4] == ["1", "PINHOLE", "320", "240"]
    assert np.allclose([float(x) for x in line[4:]], [p.K[0, 0], p.K[1, 1], p.K[0, 2] + 0.5, p.K[1, 2] + 0.5])
    j = json.loads((tmp_path / "json").read_text())["cameras"][0]
    assert np.allclose(j["opencv"]["K"], p.K) and j["model"] == "pinhole"
    # a virtual camera projects its own pixel centres' world points back onto themselves
    import cv2
    pts = cam.sensor.grid()[::40, ::40].reshape(-1, 1, 3)
    px = cv2.projectPoints(pts, p.rvec, p.t, p.K, p.dist)[0].reshape(-1, 2)
    v, u = np.mgrid[0:240:40, 0:320:40]
    assert np.allclose(px, np.stack([u.ravel(), v.ravel()], -1), atol=1e-6)


def test_telecentric_camera_exports_json_only(tmp_path, capsys):
    lens = make_lens("telecentric", seed=5, **SMALL)
    lens.true_prvm().save(tmp_path / "t.npz")
    assert main(["export", str(tmp_path / "t.npz"), "--model", "telecentric", "--format", "json",
                 "-o", str(tmp_path / "t.json")]) == 0
    assert json.loads((tmp_path / "t.json").read_text())["cameras"][0]["model"] == "telecentric"
    assert main(["export", str(tmp_path / "t.npz"), "--model", "telecentric", "--format", "opencv",
                 "-o", str(tmp_path / "t.yaml")]) == 2
    assert "no pinhole model" in capsys.readouterr().err
    assert export_text({"c": VirtualCamera(default_camera(lens.true_prvm()).sensor, "modelless")}, fmt="json")
