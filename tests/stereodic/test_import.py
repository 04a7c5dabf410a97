"""`stereodic import` per format: each camera model against an independent statement of it (OpenCV's own
cv2.projectPoints, DICe's and VIC-3D's documented models written here, with skew), and the round trip
export -> import of a rig giving back the same rays."""

import textwrap

import cv2
import numpy as np
import pytest

from calib.camera_models import CameraModel, pixel_grid, transform
from stereodic.cli import main
from stereodic.formats import import_calibration
from stereodic.stereo.rig import load_rig
from stereodic.formats.vic3d import write as vic3d_xml

W, H = 320, 240


def _look_at(centre, target, up=(0.0, -1.0, 0.0)):
    """World-to-camera R, t of a camera at `centre` looking at `target` (image rows along `up`'s opposite)."""
    z = np.subtract(target, centre) / np.linalg.norm(np.subtract(target, centre))
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    return R, -R @ np.asarray(centre, np.float64)


def _vic_pair():
    """Two skewed VIC-3D cameras looking down -z of their world frame (VIC-3D's usual frame)."""
    cams = []
    for i, cx in enumerate((-60.0, 60.0)):
        R, t = _look_at([cx, 2.0, 400.0], [0, 0, 0], up=(0.0, 1.0, 0.0))
        cams.append(CameraModel(410.0 + 5 * i, 409.0, 161.3 - 3 * i, 118.9, -0.6 + i, "opencv",
                                [0.09, -0.2, 0, 0, 0.3], R, t, W, H, f"camera {i}"))
    return cams


def _rays_in_world(prvm, world_from_rig):
    return transform(world_from_rig, prvm.origin), prvm.direction @ np.asarray(world_from_rig)[:3, :3].T


def _ray_error_px(rig, side, prvm, world_from_rig):
    """Largest distance (virtual pixels) of the imported camera's rays from the rig's virtual pinhole rays:
    each imported pixel's ray against the rig's sensor point of that pixel and the rig camera's centre."""
    o, d = _rays_in_world(prvm, world_from_rig)
    v, u = np.mgrid[0:rig.sensor.height, 0:rig.sensor.width]
    points = [rig.to_world(rig.sensor.points(u.astype(float), v.astype(float))),
              rig.to_world(np.broadcast_to(rig.camera(side).centre, o.shape))]
    err = 0.0
    for p in points:
        w = p - o
        err = max(err, np.nanmax(np.linalg.norm(w - np.sum(w * d, -1)[..., None] * d, axis=-1)))
    return err / min(rig.sensor.pitch_mm)


@pytest.fixture(scope="module")
def vic_rig(tmp_path_factory):
    path = tmp_path_factory.mktemp("vic") / "cal.xml"
    path.write_text(vic3d_xml(_vic_pair()))
    return path, import_calibration([path])


def test_vic3d_camera_against_its_documented_model(vic_rig):
    """Every pixel's imported ray projects onto that pixel through VIC-3D's model written here: radial
    kappa1..3 on the normalised coordinates, then K with skew (1e-6 px)."""
    _, imp = vic_rig
    rig = imp.result
    assert not np.allclose(rig.world_from_rig, np.eye(4))        # the cameras look along -z: turned
    for cam, prvm in zip(_vic_pair(), imp.prvms):
        far = transform(rig.world_from_rig, prvm.at_z(prvm.reference_z_mm + 50.0)).reshape(-1, 3)
        p = far @ cam.R.T + cam.t
        x, y = p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]
        r2 = x * x + y * y
        s = 1 + 0.09 * r2 - 0.2 * r2 ** 2 + 0.3 * r2 ** 3
        u = cam.fx * x * s + cam.skew * y * s + cam.cx
        v = cam.fy * y * s + cam.cy
        uv = pixel_grid(W, H)
        assert prvm.valid.all()
        assert np.abs(u - uv[:, 0]).max() < 1e-6 and np.abs(v - uv[:, 1]).max() < 1e-6


def test_opencv_camera_against_cv2_projectpoints(tmp_path):
    """A single OpenCV camera with all 14 coefficients (rational, thin prism, tilted sensor): every imported
    ray projects onto its pixel by cv2.projectPoints within 1e-6 px, over the whole image."""
    dist = np.array([-0.28, 0.09, 0.001, -0.0007, -0.01, 0.01, -0.004, 0.0015, 0.001, -0.0005, 0.0008, -0.0003,
                     0.02, -0.01])
    K = np.array([[300.0, 0, 165.3], [0, 302.0, 118.7], [0, 0, 1]])
    rvec, tvec = np.array([0.05, -0.03, 0.02]), np.array([-10.0, 5.0, 500.0])
    fs = cv2.FileStorage(str(tmp_path / "cam.yml"), cv2.FILE_STORAGE_WRITE)
    for k, v in (("camera_matrix", K), ("distortion_coefficients", dist.reshape(1, -1)), ("rvec", rvec),
                 ("tvec", tvec)):
        fs.write(k, v)
    fs.write("image_width", W)
    fs.write("image_height", H)
    fs.release()
    assert main(["import", str(tmp_path / "cam.yml"), "-o", str(tmp_path / "cam.npz")]) == 0
    from calib.prvm_file import load_prvm
    prvm = load_prvm(tmp_path / "cam.npz")
    assert np.allclose(prvm.meta["world_from_rig"], np.eye(4))
    v, u = np.nonzero(prvm.valid)
    assert prvm.valid.mean() > 0.99
    px = cv2.projectPoints(prvm.at_z(300.0)[v, u], rvec, tvec, K, dist)[0].reshape(-1, 2)
    assert np.abs(px[:, 0] - u).max() < 1e-6 and np.abs(px[:, 1] - v).max() < 1e-6


def _dice_model(x, y, model, k):
    """DICe_Camera.cpp sensor_to_image's radial models on normalised coordinates (x, y)."""
    r = np.hypot(x, y)
    powers = {"K1R1_K2R2_K3R3": (1, 2, 3), "K1R2_K2R4_K3R6": (2, 4, 6), "K1R3_K2R5_K3R7": (3, 5, 7)}[model]
    dis = sum(c * r ** p for c, p in zip(k, powers))
    return (r + dis) * x / r, (r + dis) * y / r


@pytest.mark.parametrize("model", ["K1R1_K2R2_K3R3", "K1R2_K2R4_K3R6", "K1R3_K2R5_K3R7"])
def test_dice_camera_against_its_documented_model(tmp_path, model):
    """A DICe camera system (Euler angles, relative extrinsics, FS skew): each camera's rays project onto
    their pixels through DICe's model written here within 1e-6 px."""
    k = {"K1R1_K2R2_K3R3": (-0.01, 0.05, -0.02), "K1R2_K2R4_K3R6": (0.08, -0.05, 0.01),
         "K1R3_K2R5_K3R7": (0.1, -0.1, 0.05)}[model]
    text = textwrap.dedent(f"""\
        <ParameterList>
          <Parameter name="xml_file_format" type="string" value="DICe_xml_camera_system_file" />
          <Parameter name="system_type_3D" type="string" value="GENERIC_SYSTEM" />
          <Parameter name="extrinsics_relative_camera_to_camera" type="bool" value="true" />
          <ParameterList name="CAMERA 0">
            <Parameter name="CX" type="double" value="158.2" /><Parameter name="CY" type="double" value="121.5" />
            <Parameter name="FX" type="double" value="420.0" /><Parameter name="FY" type="double" value="421.5" />
            <Parameter name="FS" type="double" value="0.8" />
            <Parameter name="K1" type="double" value="{k[0]}" /><Parameter name="K2" type="double" value="{k[1]}" />
            <Parameter name="K3" type="double" value="{k[2]}" />
            <Parameter name="LENS_DISTORTION_MODEL" type="string" value="{model}" />
            <Parameter name="IMAGE_HEIGHT_WIDTH" type="string" value="{{ {H}, {W} }}" />
          </ParameterList>
          <ParameterList name="CAMERA 1">
            <Parameter name="CX" type="double" value="162.0" /><Parameter name="CY" type="double" value="119.0" />
            <Parameter name="FX" type="double" value="418.0" /><Parameter name="FY" type="double" value="418.5" />
            <Parameter name="FS" type="double" value="-0.5" />
            <Parameter name="K1" type="double" value="{k[0]}" /><Parameter name="K2" type="double" value="{k[1]}" />
            <Parameter name="K3" type="double" value="{k[2]}" />
            <Parameter name="LENS_DISTORTION_MODEL" type="string" value="{model}" />
            <Parameter name="IMAGE_HEIGHT_WIDTH" type="string" value="{{ {H}, {W} }}" />
            <Parameter name="ALPHA" type="double" value="0.5" /><Parameter name="BETA" type="double" value="-15.0" />
            <Parameter name="GAMMA" type="double" value="0.3" />
            <Parameter name="TX" type="double" value="-110.0" /><Parameter name="TY" type="double" value="1.0" />
            <Parameter name="TZ" type="double" value="25.0" />
          </ParameterList>
        </ParameterList>""")
    (tmp_path / "cal.xml").write_text(text)
    imp = import_calibration([tmp_path / "cal.xml"])
    assert imp.format == "dice"
    a, b, g = np.radians([0.5, -15.0, 0.3])
    R1 = (np.array([[np.cos(g), -np.sin(g), 0], [np.sin(g), np.cos(g), 0], [0, 0, 1]])
          @ np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
          @ np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]]))
    poses = [(np.eye(3), np.zeros(3)), (R1, np.array([-110.0, 1.0, 25.0]))]   # camera 0 is the world
    intr = [(158.2, 121.5, 420.0, 421.5, 0.8), (162.0, 119.0, 418.0, 418.5, -0.5)]
    wfr = imp.result.world_from_rig
    for prvm, (R, t), (cx, cy, fx, fy, fs) in zip(imp.prvms, poses, intr):
        p = transform(wfr, prvm.at_z(prvm.reference_z_mm + 30.0)).reshape(-1, 3) @ R.T + t
        xd, yd = _dice_model(p[:, 0] / p[:, 2], p[:, 1] / p[:, 2], model, k)
        uv = pixel_grid(W, H)
        ok = prvm.valid.ravel()
        assert ok.mean() > 0.99
        assert np.abs(fx * xd + fs * yd + cx - uv[:, 0])[ok].max() < 1e-6
        assert np.abs(fy * yd + cy - uv[:, 1])[ok].max() < 1e-6


def test_dice_legacy_txt_is_the_xml(tmp_path):
    """cal.txt (camera 0's and 1's CX CY FX FY FS K1 K2 K3, camera 1's Euler angles and T relative to
    camera 0, height, width) gives the rays of the equivalent XML."""
    vals = [158.2, 121.5, 420.0, 421.5, 0.8, -0.01, 0.05, -0.02, 162.0, 119.0, 418.0, 418.5, -0.5, -0.01, 0.05,
            -0.02, 0.5, -15.0, 0.3, -110.0, 1.0, 25.0, H, W]
    (tmp_path / "cal.txt").write_text("# legacy DICe calibration\n" + "\n".join(f"{v} # value" if i == 0 else
                                                                               str(v) for i, v in enumerate(vals)))
    imp = import_calibration([tmp_path / "cal.txt"])
    cams = imp.cameras
    assert imp.format == "dice" and cams[0].lens == "radial" and cams[1].skew == -0.5
    assert np.allclose(cams[0].R, np.eye(3)) and np.allclose(cams[1].t, [-110.0, 1.0, 25.0])


ROUND_TRIP = ["opencv", "dice", "vic3d", "mrcal"]


@pytest.mark.parametrize("fmt", ROUND_TRIP)
def test_export_then_import_gives_back_the_rays(vic_rig, tmp_path, fmt):
    """Our rig (from a VIC-3D file in a -z world frame) exported and imported again: every ray of the two
    exported virtual pinhole cameras is the rig's own within 1e-6 virtual pixel, in the file's world frame."""
    path, imp = vic_rig
    rig_file = tmp_path / "rig.npz"
    from stereodic.stereo.rig import save_rig
    save_rig(rig_file, imp.result)
    rig = load_rig(rig_file)
    out = tmp_path / ("out" if fmt == "mrcal" else "out.xml" if fmt in ("dice", "vic3d") else "out.yml")
    assert main(["export", str(rig_file), "--format", fmt, "-o", str(out)]) == 0
    files = [out / "left.cameramodel", out / "right.cameramodel"] if fmt == "mrcal" else [out]
    back = import_calibration(files, fmt=fmt)
    assert back.format == fmt
    for side, prvm in zip(("left", "right"), back.prvms):
        assert prvm.valid.all() and (prvm.width, prvm.height) == (rig.sensor.width, rig.sensor.height)
        assert _ray_error_px(rig, side, prvm, back.result.world_from_rig) < 1e-6


def test_kalibr_camchain_gives_the_rays(vic_rig, tmp_path):
    """A Kalibr camchain (pinhole-radtan cam0, cam1 with T_cn_cnm1 in metres) of the rig's virtual cameras,
    written here: the imported rays are the rig's (in cam0's frame, Kalibr's world) within 1e-6 px; an
    equidistant camera's rays follow the fisheye model written here."""
    _, imp = vic_rig
    rig = imp.result
    from stereodic.stereo.export import rig_pinholes
    left, right = rig_pinholes(rig)
    rel_R = right.R @ left.R.T
    rel_t = (right.t - rel_R @ left.t) / 1000.0
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rel_R, rel_t

    def cam(p, extra=""):
        return (f"  camera_model: pinhole\n  distortion_coeffs: [0.0, 0.0, 0.0, 0.0]\n  distortion_model: radtan\n"
                f"  intrinsics: [{float(p.K[0, 0])!r}, {float(p.K[1, 1])!r}, {float(p.K[0, 2])!r}, {float(p.K[1, 2])!r}]\n"
                f"  resolution: [{p.width}, {p.height}]\n  rostopic: /cam/image_raw\n{extra}")
    rows = "".join(f"  - [{', '.join(repr(float(v)) for v in row)}]\n" for row in T)
    (tmp_path / "camchain.yaml").write_text("cam0:\n" + cam(left) + "cam1:\n  T_cn_cnm1:\n" + rows + cam(right))
    back = import_calibration([tmp_path / "camchain.yaml"])
    assert back.format == "kalibr"
    cam0_from_world = np.eye(4)
    cam0_from_world[:3, :3], cam0_from_world[:3, 3] = left.R, left.t
    world_from_cam0 = np.linalg.inv(cam0_from_world)
    for side, prvm in zip(("left", "right"), back.prvms):
        assert _ray_error_px(rig, side, prvm, world_from_cam0 @ back.result.world_from_rig) < 1e-6

    k = (0.05, -0.01, 0.004, -0.001)
    (tmp_path / "equi.yaml").write_text(
        "cam0:\n  camera_model: pinhole\n  distortion_model: equidistant\n"
        f"  distortion_coeffs: [{', '.join(map(str, k))}]\n  intrinsics: [200.0, 201.0, 160.5, 119.5]\n"
        f"  resolution: [{W}, {H}]\n")
    prvm = import_calibration([tmp_path / "equi.yaml"]).result
    d = prvm.direction.reshape(-1, 3)
    theta = np.arccos(d[:, 2])
    td = theta * (1 + k[0] * theta ** 2 + k[1] * theta ** 4 + k[2] * theta ** 6 + k[3] * theta ** 8)
    phi = np.arctan2(d[:, 1], d[:, 0])
    uv = pixel_grid(W, H)
    assert np.abs(200.0 * td * np.cos(phi) + 160.5 - uv[:, 0]).max() < 1e-6
    assert np.abs(201.0 * td * np.sin(phi) + 119.5 - uv[:, 1]).max() < 1e-6


def test_mrcal_opencv8_against_cv2_projectpoints(tmp_path):
    """A mrcal LENSMODEL_OPENCV8 camera (rt_fromref extrinsics, comments, a bytes literal as mrcal writes
    its optimization inputs): every ray projects onto its pixel by cv2.projectPoints within 1e-6 px."""
    dist = [-0.2, 0.05, 0.001, -0.0005, 0.01, 0.02, -0.01, 0.003]
    rt = [0.02, -0.04, 0.01, 12.0, -3.0, 450.0]
    (tmp_path / "cam.cameramodel").write_text(
        "# generated by a test\n{\n    'lensmodel':  'LENSMODEL_OPENCV8',\n"
        "    # intrinsics are fx,fy,cx,cy,distortion0,distortion1,....\n"
        f"    'intrinsics': [ 310.0, 311.0, 161.0, 118.0, {', '.join(map(str, dist))},],\n"
        f"    'extrinsics': [ {', '.join(map(str, rt))},],\n    'imagersize': [ {W}, {H},],\n"
        "    'optimization_inputs': b'P)h>@6aWAK2mk',\n}\n")
    imp = import_calibration([tmp_path / "cam.cameramodel"])
    prvm = imp.result
    assert imp.format == "mrcal" and prvm.valid.all()
    v, u = np.nonzero(prvm.valid)
    K = np.array([[310.0, 0, 161.0], [0, 311.0, 118.0], [0, 0, 1]])
    px = cv2.projectPoints(transform(np.asarray(prvm.meta["world_from_rig"]), prvm.at_z(600.0)[v, u]),
                           np.array(rt[:3]), np.array(rt[3:]), K, np.array(dist))[0].reshape(-1, 2)
    assert np.abs(px[:, 0] - u).max() < 1e-6 and np.abs(px[:, 1] - v).max() < 1e-6
