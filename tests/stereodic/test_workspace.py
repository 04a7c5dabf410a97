"""`stereodic view`: the workspace's access rules over plain HTTP, its result reader against dic.csv, and
the whole path in a real headless Chromium (marked `browser`): a simulated DIC dataset, a polygon region
drawn on the original image, the run started and followed, the state slider, a clicked point's history
against dic.csv, an extensometer against `stereodic gauge`, a load CSV's stress-strain, a calibration and a scan."""

import csv
import json
import shutil
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from stereodic.cli import main


def _get(url, cookie=None):
    req = urllib.request.Request(url, headers={"Cookie": cookie} if cookie else {})
    try:
        with urllib.request.urlopen(req, timeout=30) as r:
            return r.status, r.read().decode("latin-1"), r.headers
    except urllib.error.HTTPError as e:
        return e.code, e.read().decode("latin-1"), e.headers


@pytest.fixture(scope="module")
def secret_dir(tmp_path_factory):
    """A served folder with an image, and a file beside it that must not be served."""
    from calib.imageio import write_gray
    root = tmp_path_factory.mktemp("served")
    served = root / "served"
    served.mkdir()
    write_gray(served / "img.png", np.arange(64 * 48, dtype=np.uint16).reshape(48, 64).astype(np.uint8))
    (root / "secret.txt").write_text("the lab's secret\n")
    import open3d as o3d
    v = np.random.default_rng(0).normal(size=(200, 3))
    o3d.io.write_point_cloud(str(root / "cloud.ply"), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(
        10.0 * v / np.linalg.norm(v, axis=1)[:, None])))
    return served


def test_other_host_needs_a_token(capsys):
    assert main(["view", "--host", "0.0.0.0", "--no-browser", "."]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--host" in err and "--token" in err
    assert main(["view", "--host", "0.0.0.0", "--token", "short", "--no-browser", "."]) == 2
    assert "--token" in capsys.readouterr().err


def test_token_and_path_traversal_over_http(secret_dir):
    from stereodic.workspace.server import start
    token = "0123456789abcdef0123"
    ws = start([secret_dir], host="127.0.0.1", token=token, background=True)
    try:
        base = ws.url.split("?")[0]
        assert _get(base)[0] == 403                                  # no token: refused
        assert _get(base + "?token=wrong-wrong-wrong-wrong")[0] == 403
        status, body, headers = _get(ws.url)
        assert status == 200 and "stereodic view" in body
        cookie = headers["Set-Cookie"].split(";")[0]
        img = urllib.parse.quote(str(secret_dir / "img.png"))
        status, body, _ = _get(f"{base}image?path={img}", cookie)    # the token's cookie: served
        assert status == 200 and body.startswith("\x89PNG")
        assert _get(f"{base}image?path={img}")[0] == 403              # no cookie, no token
        for crafted in ("../secret.txt", "img.png/../../secret.txt", str(secret_dir / ".." / "secret.txt"),
                        "%2e%2e/secret.txt", "/etc/passwd"):
            status, body, _ = _get(f"{base}image?path={crafted if '%' in crafted else urllib.parse.quote(crafted)}",
                                   cookie)
            assert status == 403 and "secret" not in body.replace("secret.txt", "") and "root:" not in body
            assert "outside the folders" in body and len(body.strip().splitlines()) == 1
        status, body, _ = _get(f"{base}image", cookie)                 # a bad parameter: one line, no traceback
        assert status == 400 and "Traceback" not in body and len(body.strip().splitlines()) == 1
        # the page asked for a path outside (the same check in the page's own callback)
        payload = {"output": "..page.children...page-path.children..", "outputs": [
            {"id": "page", "property": "children"}, {"id": "page-path", "property": "children"}],
            "inputs": [{"id": "url", "property": "search", "value": "?path=../secret.txt"}],
            "changedPropIds": ["url.search"], "state": []}
        req = urllib.request.Request(base + "_dash-update-component", data=json.dumps(payload).encode(),
                                     headers={"Content-Type": "application/json", "Cookie": cookie})
        with urllib.request.urlopen(req, timeout=30) as r:
            answer = r.read().decode()
        assert "outside the folders" in answer and "the lab's secret" not in answer
        # a callback's own path (a page's stored path, sent back by the browser) is checked the same way
        payload = {"output": "..cloud.figure...about.children..", "outputs": [
            {"id": "cloud", "property": "figure"}, {"id": "about", "property": "children"}],
            "inputs": [{"id": "scan-shape", "property": "value", "value": "sphere"}],
            "changedPropIds": ["scan-shape.value"],
            "state": [{"id": "scan-path", "property": "data", "value": str(secret_dir.parent / "cloud.ply")}]}
        req = urllib.request.Request(base + "_dash-update-component", data=json.dumps(payload).encode(),
                                     headers={"Content-Type": "application/json", "Cookie": cookie})
        with urllib.request.urlopen(req, timeout=30) as r:
            answer = r.read().decode()
        assert "outside the folders" in answer and "sphere of radius" not in answer
    finally:
        ws.stop()


def _csv(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def dic_run(dic_sim, tmp_path_factory):
    """`stereodic dic` on the shared simulated dataset (3 states); its printed lines in out/printed.txt."""
    import contextlib
    import io
    out = tmp_path_factory.mktemp("ws_run") / "run"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert main(["dic", str(dic_sim / "rig.npz"), str(dic_sim), "-o", str(out), "--step", "8", "--no-vtk",
                     "--no-plot"]) == 0
    (out / "printed.txt").write_text(printed.getvalue())
    return out


def test_rig_health_is_what_dic_reported(dic_run):
    from stereodic.workspace.dic_view import rig_health, source
    figure, line = rig_health(source(dic_run))
    said = next(t for t in (dic_run / "printed.txt").read_text().splitlines() if t.startswith("epipolar error"))
    assert line.startswith(said) and "within what the calibration allows" in line
    assert figure.data[0].x.size == int(said.split(" over ")[1].split()[0])


def test_result_reader_against_dic_csv(dic_run):
    from stereodic.workspace.results import DicSource
    rows = [r for r in _csv(dic_run / "dic.csv") if r["converged"] == "1"]
    for src in (DicSource(dic_run), DicSource(dic_run / "dic.npz")):     # the run folder and dic.npz
        assert src.count == 3 and src.reference_image().name == "cam0.png"
        by_state = {}
        for r in rows:
            by_state.setdefault(int(r["state"]), []).append(r)
        r = by_state[2][len(by_state[2]) // 2]
        ref = next(q for q in by_state[0] if q["x"] == r["x"] and q["y"] == r["y"])
        i = src.nearest(float(ref["left_x0"]), float(ref["left_y0"]))
        assert abs(src.x[i] - float(ref["left_x0"])) < 1e-5
        hist = src.history(i, "dX")
        want = [float(next(q for q in by_state[k] if q["x"] == r["x"] and q["y"] == r["y"])["dX"]) for k in range(3)]
        np.testing.assert_allclose(hist, want, atol=2e-6)
        exx = src.values(2, "exx")
        assert abs(np.nanmedian(exx) - 1e6 * np.median([float(q["exx"]) for q in by_state[2]
                                                        if q["strain_valid"] == "1"])) < 1.0
        lo, hi = src.limits("exx")
        assert lo == -hi and hi > 9000          # fixed, symmetric, covering the 1 % tension


# ---------------------------------------------------------------------------------------- the browser

CHROMIUM, DRIVER = shutil.which("chromium"), shutil.which("chromedriver")


@pytest.fixture(scope="module")
def browser():
    if not (CHROMIUM and DRIVER):
        pytest.fail("Debian's chromium and chromium-driver are needed (./run test installs them)")
    from stereodic.bench.view import headless_chromium
    driver, profile = headless_chromium()
    yield driver
    driver.quit()
    shutil.rmtree(profile, ignore_errors=True)


def _wait(what, timeout=60.0, every=0.2):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        got = what()
        if got:
            return got
        time.sleep(every)
    raise AssertionError(f"timed out after {timeout} s")


def _plot(driver, graph_id, attr="data"):
    return driver.execute_script(f"var g = document.querySelector('#{graph_id} .js-plotly-plot');"
                                 f"return g && g.{attr} ? JSON.parse(JSON.stringify(g.{attr})) : null;")


def _array(driver, graph_id, trace, key):
    """A trace's array as plotted (typed arrays too), float64."""
    return np.array(driver.execute_script(
        f"var g = document.querySelector('#{graph_id} .js-plotly-plot');"
        f"return Array.from(g._fullData[{trace}].{key});"), np.float64)


def _to_screen(driver, graph_id, x, y):
    """Page pixel offsets from the graph's drag layer's top-left corner of data point (x, y)."""
    return driver.execute_script(
        f"var g = document.querySelector('#{graph_id} .js-plotly-plot'); var l = g._fullLayout;"
        "return [l.xaxis.l2p(arguments[0]), l.yaxis.l2p(arguments[1])];", x, y)


def _draw(driver, graph_id, points, closed=False):
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By
    drag = driver.find_element(By.CSS_SELECTOR, f"#{graph_id} .nsewdrag")
    w, h = drag.size["width"], drag.size["height"]
    px = [_to_screen(driver, graph_id, x, y) for x, y in points]
    chain = ActionChains(driver, duration=50).move_to_element_with_offset(drag, px[0][0] - w / 2, px[0][1] - h / 2)
    chain.click_and_hold()
    prev = px[0]
    for p in px[1:] + ([px[0]] if closed else []):
        steps = 6
        for s in range(1, steps + 1):
            target = (prev[0] + (p[0] - prev[0]) * s / steps, prev[1] + (p[1] - prev[1]) * s / steps)
            chain.move_to_element_with_offset(drag, target[0] - w / 2, target[1] - h / 2)
        prev = p
    chain.release().perform()


def _gauge_strain(result, ends, out):
    """The extensometer's strain (microstrain) per state as the `stereodic gauge` command writes it."""
    assert main(["gauge", str(result), "--extensometer", ends, "-o", str(out)]) == 0
    return [float(r["strain"]) * 1e6 for r in _csv(out / "extensometers.csv")]


@pytest.mark.browser
def test_workspace_in_a_browser(browser, dic_sim, tmp_path):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    from stereodic.workspace.server import start
    d = browser
    shots = tmp_path / "shots"
    shots.mkdir()
    work = tmp_path / "work"
    work.mkdir()
    ws = start([dic_sim, work], background=True)
    try:
        base = ws.url
        # -- set up a run: the dataset's page, a polygon drawn on the original left image
        d.get(base + "?path=" + urllib.parse.quote(str(dic_sim)))
        _wait(lambda: _plot(d, "noise"), 90)
        d.find_element(By.ID, "clear-region").click()
        _wait(lambda: not (_plot(d, "ref-image", "layout") or {}).get("shapes"))
        polygon = [(40, 40), (190, 45), (185, 150), (45, 150)]
        _draw(d, "ref-image", polygon, closed=True)
        _wait(lambda: (_plot(d, "ref-image", "layout") or {}).get("shapes"))
        d.save_screenshot(str(shots / "1-setup.png"))
        out = work / "run"
        field = d.find_element(By.ID, "setup-output")
        field.send_keys(Keys.CONTROL, "a")
        field.send_keys(str(out))
        step = d.find_element(By.ID, "setup-step")
        step.send_keys(Keys.CONTROL, "a")
        step.send_keys("8")
        d.find_element(By.ID, "start").click()
        _wait(lambda: "stereodic dic" in d.find_element(By.ID, "command").text, 30)
        _wait(lambda: d.find_elements(By.ID, "open-results") or "stopped" in d.find_element(By.ID, "progress").text,
              240, 1.0)
        d.save_screenshot(str(shots / "2-run-done.png"))
        assert d.find_elements(By.ID, "open-results"), d.find_element(By.ID, "progress").text
        record = json.loads((out / "workspace.json").read_text())
        drawn = np.array(record["region"][0]["points"])
        assert len(record["region"]) == 1 and len(drawn) >= 4
        assert np.abs(drawn.min(0) - [40, 40]).max() < 3 and np.abs(drawn.max(0) - [190, 150]).max() < 3
        rows = _csv(out / "dic.csv")
        from matplotlib.path import Path as MPath
        ref_rows = [r for r in rows if r["state"] == "0" and r["converged"] == "1"]
        inside = MPath(drawn).contains_points([(float(r["left_x0"]), float(r["left_y0"])) for r in ref_rows],
                                              radius=1.5)
        assert len(ref_rows) > 50 and inside.mean() > 0.99      # the points are where the region was drawn
        assert record["command"].startswith("stereodic dic ") and "--mask" in record["command"]
        assert record["settings"]["step"] == 8 and "--step 8" in record["command"]

        # -- the results: the state slider, a point's history against dic.csv
        d.find_element(By.ID, "open-results").click()
        _wait(lambda: _plot(d, "field"), 60)
        handle = d.find_element(By.CSS_SELECTOR, "#state [role=slider]")
        handle.click()
        handle.send_keys(Keys.END)
        _wait(lambda: "tension" in (_plot(d, "field", "layout") or {}).get("title", {}).get("text", ""))
        d.save_screenshot(str(shots / "3-results-state2.png"))
        target = ref_rows[len(ref_rows) // 2]           # click on a measured point, where it is in the image
        tx, ty = float(target["left_x0"]), float(target["left_y0"])
        from selenium.webdriver.common.action_chains import ActionChains
        drag = d.find_element(By.CSS_SELECTOR, "#field .nsewdrag")
        px = _to_screen(d, "field", tx, ty)
        ActionChains(d).move_to_element_with_offset(drag, px[0] - drag.size["width"] / 2,
                                                    px[1] - drag.size["height"] / 2).click().perform()
        _wait(lambda: _plot(d, "curve"))
        title = _plot(d, "curve", "layout")["title"]["text"]
        at = [float(v) for v in title.split("(")[1].split(")")[0].split(",")]
        row0 = min(ref_rows, key=lambda r: np.hypot(float(r["left_x0"]) - at[0], float(r["left_y0"]) - at[1]))
        assert np.hypot(float(row0["left_x0"]) - at[0], float(row0["left_y0"]) - at[1]) < 0.06
        assert np.hypot(at[0] - tx, at[1] - ty) < 8.0       # the clicked point or a neighbour (a cell is a step)
        truth = [float(next(r for r in rows if r["state"] == str(k) and r["x"] == row0["x"] and r["y"] == row0["y"])
                       ["exx"]) * 1e6 for k in range(3)]
        np.testing.assert_allclose(_array(d, "curve", 0, "y"), truth, atol=0.06)   # dic.csv's %.7f: 0.05 microstrain
        d.save_screenshot(str(shots / "4-history.png"))

        # -- an extensometer drawn on the image against `stereodic gauge`
        d.find_element(By.CSS_SELECTOR, "#tool input[value=extensometer]").click()
        _wait(lambda: (_plot(d, "field", "layout") or {}).get("dragmode") == "drawline")
        _draw(d, "field", [(70, 80), (160, 85)])
        _wait(lambda: _plot(d, "curve") if "extensometer" in
                    (_plot(d, "curve", "layout") or {}).get("title", {}).get("text", "") else None, 60)
        shape = _plot(d, "field", "layout")["shapes"][-1]
        ends = ",".join(f"{shape[k]:.6f}" for k in ("x0", "y0", "x1", "y1"))
        want = _gauge_strain(out, ends, tmp_path / "gauge")
        np.testing.assert_allclose(_array(d, "curve", 0, "y"), want, atol=0.01)
        assert abs(want[2] - 1e4) < 500          # the simulated 1 % stretch along x
        # -- the testing machine's load (its own image index column) against the extensometer: stress-strain
        load = work / "machine.csv"
        load.write_text("Image,Force [N]\n0,0\n1,120.5\n2,2410\n3,2500\n")
        d.find_element(By.CSS_SELECTOR, "#load-upload input[type=file]").send_keys(str(load))
        d.find_element(By.ID, "load-area").send_keys("12.5")
        _wait(lambda: _plot(d, "stress-strain") and "stress-strain" in
              (_plot(d, "stress-strain", "layout") or {}).get("title", {}).get("text", ""), 30)
        np.testing.assert_allclose(_array(d, "stress-strain", 0, "y"), [0.0, 120.5 / 12.5, 2410 / 12.5], rtol=1e-9)
        np.testing.assert_allclose(_array(d, "stress-strain", 0, "x"), want, atol=0.01)
        d.save_screenshot(str(shots / "5-extensometer.png"))

        # -- a calibration (a PRVM file) and a scan (a PLY cloud of a known sphere)
        d.get(base + "?path=" + urllib.parse.quote(str(dic_sim / "truth_cam0.npz")))
        about = _wait(lambda: d.find_elements(By.ID, "about") and d.find_element(By.ID, "about").text, 60)
        assert "PRVM of camera" in about
        _wait(lambda: len(d.find_elements(By.CSS_SELECTOR, ".map .js-plotly-plot")) >= 1)
        d.save_screenshot(str(shots / "6-calibration.png"))
        import open3d as o3d
        rng = np.random.default_rng(3)
        v = rng.normal(size=(3000, 3))
        pts = np.array([5.0, -2.0, 300.0]) + 20.0 * v / np.linalg.norm(v, axis=1)[:, None]
        pts += rng.normal(scale=0.01, size=pts.shape)
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
        o3d.io.write_point_cloud(str(work / "sphere.ply"), cloud)
        d.get(base + "?path=" + urllib.parse.quote(str(work / "sphere.ply")))
        _wait(lambda: d.find_elements(By.CSS_SELECTOR, "#scan-shape input[value=sphere]"), 60)
        d.find_element(By.CSS_SELECTOR, "#scan-shape input[value=sphere]").click()
        about = _wait(lambda: "sphere of radius" in d.find_element(By.ID, "about").text
                      and d.find_element(By.ID, "about").text, 60)
        radius = float(about.split("sphere of radius ")[1].split(" mm")[0])
        rms = float(about.split("RMS ")[1].split(" mm")[0])
        assert abs(radius - 20.0) < 0.005 and abs(rms - 0.01) < 0.001     # the simulated 0.01 mm noise
        assert _plot(d, "cloud")[0]["type"] == "scatter3d"
        d.save_screenshot(str(shots / "7-scan.png"))
    finally:
        ws.stop()


def test_region_on_image_pairs_goes_to_the_rectified_mask(dic_sim, tmp_path):
    """A folder of image pairs (DICe's naming) is set up like a dataset; the polygon drawn on the original
    left image becomes the rectified mask whose pixels sample the original inside it (checked through the
    rig's own maps, pixel by pixel), with the hole left out."""
    from matplotlib.path import Path as MPath

    from stereodic.stereo.rig import load_rig
    from stereodic.workspace.app import kind_of
    from stereodic.workspace.region import Polygon
    from stereodic.workspace.setup_view import write_run_files
    pairs = tmp_path / "pairs"
    pairs.mkdir()
    for k in range(3):
        for cam, side in (("cam0", 0), ("cam1", 1)):
            shutil.copy(dic_sim / f"s{k:03d}" / f"{cam}.png", pairs / f"img_{k:04d}_{side}.png")
    assert kind_of(pairs) == "setup"
    outline = np.array([[40.0, 40.0], [190.0, 45.0], [185.0, 150.0], [45.0, 150.0]])
    hole = np.array([[100.0, 80.0], [130.0, 80.0], [130.0, 110.0], [100.0, 110.0]])
    out = tmp_path / "run"
    command = write_run_files(out, dic_sim / "rig.npz", pairs, [Polygon(outline), Polygon(hole, hole=True)],
                              {"subset": 21, "step": 8, "strain_window": 5})
    assert command[3:5] == ["--images", str(pairs)] and "--mask" in command
    from calib.imageio import read_gray
    mask = read_gray(out / "region_mask.png") > 0
    imm = load_rig(dic_sim / "rig.npz").left.imm
    assert mask.shape == imm.shape
    sampled = np.column_stack([imm.map_x[imm.valid], imm.map_y[imm.valid]])
    m = mask[imm.valid]
    deep = MPath(outline).contains_points(sampled, radius=-2.0) & ~MPath(hole).contains_points(sampled, radius=2.0)
    near = MPath(outline).contains_points(sampled, radius=2.0) & ~MPath(hole).contains_points(sampled, radius=-2.0)
    assert m[deep].all() and not m[~near].any() and m.sum() > 1000
    record = json.loads((out / "workspace.json").read_text())
    assert [p["hole"] for p in record["region"]] == [False, True] and len(record["left_images"]) == 3


def test_map_in_the_specimen_frame(dic_run):
    """dX, dY, dZ in the specimen's frame: the same vectors turned (their lengths kept), dZ along the normal
    of the plane fitted to state 0's points (an SVD here, not the frame's own fit)."""
    from stereodic.workspace.dic_view import source
    rig, spec = source(dic_run, "rig"), source(dic_run, "specimen")
    d_rig = np.stack([rig.values(1, q) for q in ("dX", "dY", "dZ")], 1)
    d_spec = np.stack([spec.values(1, q) for q in ("dX", "dY", "dZ")], 1)
    ok = np.isfinite(d_rig).all(1)
    assert ok.sum() > 100
    np.testing.assert_allclose(np.linalg.norm(d_spec[ok], axis=1), np.linalg.norm(d_rig[ok], axis=1), atol=1e-9)
    with np.load(dic_run / "dic.npz") as z:
        p0 = z["points"][0].reshape(-1, 3)[rig.index]
    p0 = p0[np.isfinite(p0).all(1)]
    normal = np.linalg.svd(p0 - p0.mean(0))[2][2]
    np.testing.assert_allclose(np.abs(d_spec[ok, 2]), np.abs(d_rig[ok] @ normal), atol=2e-4)


def test_calibration_page_error_map_against_its_truth(dic_sim, tmp_path):
    """A PRVM whose dataset holds a truth.npz gets the ray error map: rays moved by half a footprint along
    x on every plane show 0.5 camera px everywhere."""
    from calib.evaluate import footprint_mm, working_plane
    from calib.prvm_file import load_prvm
    from stereodic.workspace.access import Access
    from stereodic.workspace.other_views import prvm_layout
    data = tmp_path / "dataset"
    data.mkdir()
    shutil.copy(dic_sim / "truth_cam0.npz", data / "truth.npz")
    truth = load_prvm(data / "truth.npz")
    with np.load(data / "truth.npz") as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(str(arrays["meta"]))
    meta["dataset"] = str(data)
    arrays["meta"] = np.array(json.dumps(meta))
    arrays["origin"] = arrays["origin"] + [0.5 * footprint_mm(truth, working_plane(truth)), 0.0, 0.0]
    np.savez(tmp_path / "cam.npz", **arrays)
    page = prvm_layout(tmp_path / "cam.npz", Access([tmp_path]))
    figures = [g.children.figure for g in page.children[1].children]
    error = next(f for f in figures if f.layout.title.text.startswith("ray error"))
    z = np.asarray(error.data[0].z, np.float64)
    assert np.nanmax(np.abs(z - 0.5)) < 0.02 and "RMS 0.5" in error.layout.title.text


def _image_pairs(dic_sim, folder):
    """A newcomer's folder: the simulated run's 3 states as image pairs img_KKKK_0/1.png, nothing else."""
    folder.mkdir()
    for k in range(3):
        for cam, side in (("cam0", 0), ("cam1", 1)):
            shutil.copy(dic_sim / f"s{k:03d}" / f"{cam}.png", folder / f"img_{k:04d}_{side}.png")
    return folder


@pytest.mark.browser
def test_from_image_pairs_and_two_calibrations(browser, dic_sim, tmp_path):
    """A newcomer's folder: image pairs and the two cameras' PRVM files, no rig: the page makes the rig
    with `stereodic rig` (the same rig as the command's, byte for byte in its arrays), then sets the run up."""
    from selenium.webdriver.common.by import By

    from stereodic.workspace.server import start
    d = browser
    folder = _image_pairs(dic_sim, tmp_path / "lab")
    for cam in ("cam0", "cam1"):
        shutil.copy(dic_sim / f"truth_{cam}.npz", folder / f"{cam}.npz")
    ws = start([folder], background=True)
    try:
        d.get(ws.url)
        _wait(lambda: d.find_elements(By.ID, "make-rig"), 60)
        d.find_element(By.ID, "make-rig").click()
        _wait(lambda: d.find_elements(By.ID, "open-setup") or d.find_element(By.ID, "rig-message").text, 120)
        assert d.find_elements(By.ID, "open-setup"), d.find_element(By.ID, "rig-message").text
        assert main(["rig", str(folder / "cam0.npz"), str(folder / "cam1.npz"), "-o", str(tmp_path / "rig.npz")]) == 0
        with np.load(folder / "rig.npz") as a, np.load(tmp_path / "rig.npz") as b:
            assert all(np.array_equal(a[k], b[k], equal_nan=True) for k in b.files if k != "meta")
        d.find_element(By.ID, "open-setup").click()
        _wait(lambda: _plot(d, "noise"), 90)
        assert "3 states" in d.find_element(By.ID, "setup-about").text
    finally:
        ws.stop()


REAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "dice-stereo-list"


@pytest.mark.skipif(not REAL.is_dir(), reason="the DICe stereo_list images are not present")
def test_automatic_region_finds_the_real_specimen():
    """On the real DICe stereo_list reference image the automatic region holds DICe's own ROI (the
    rectangle (160, 300)-(1100, 540) of roi.dat) and leaves out the two grips above and below it."""
    from matplotlib.path import Path as MPath

    from stereodic.workspace.region import original_mask
    from stereodic.workspace.region import shape_polygon
    from stereodic.workspace.setup_view import automatic_shapes
    polygons = [shape_polygon(s) for s in automatic_shapes(REAL / "images" / "img_0000_0.tif")]
    assert len(polygons) == 1 and not polygons[0].hole
    outline = MPath(polygons[0].points)
    ys, xs = np.mgrid[300:541:20, 160:1101:20]
    assert outline.contains_points(np.column_stack([xs.ravel(), ys.ravel()])).all()
    mask = original_mask(polygons, (1280, 800))
    assert not mask[:200].any() and not mask[650:].any()      # the grips' speckle is not the specimen's


def test_further_options_name_no_file():
    """The page's further options go to `stereodic dic` as typed, but none that names a file (the run
    reads only what the workspace serves)."""
    from calib.errors import InputError
    from stereodic.workspace.setup_view import extra_options
    assert extra_options("--vertical-search 50 --max-gap=100 --incremental") == \
        ["--vertical-search", "50", "--max-gap=100", "--incremental"]
    for bad, word in (("--mask /etc/x.png", "--mask"), ("-o /tmp/elsewhere", "-o"), ("--max-gap", "needs a value")):
        with pytest.raises(InputError, match=word):
            extra_options(bad)


def test_dic2d_states_number_as_the_gauges_do(tmp_path):
    """A dic2d result in the workspace: state 0 is the reference image and deformed image k is state k + 1,
    as in `stereodic gauge`, so that the slider's state and a gauge curve's state are the same image; the
    history of u at a point is 0 then the dic2d CSV's u, and the simulated truth's shift is what it measures."""
    from stereodic.gauge.result import open_gauge_result
    from stereodic.workspace.results import DicSource
    sim = tmp_path / "sim"
    assert main(["simulate", "dic2d", "--width", "200", "--height", "160", "--shift", "3.4,-1.2", "-o", str(sim)]) == 0
    out = tmp_path / "r.csv"
    assert main(["dic2d", str(sim / "reference.png"), str(sim / "moved.png"), "--step", "10", "-o", str(out),
                 "--npz", str(tmp_path / "r.npz")]) == 0
    src, gauge = DicSource(tmp_path / "r.npz"), open_gauge_result(tmp_path / "r.npz")
    assert src.count == gauge.count == 2
    assert src.labels() == gauge.labels
    rows = [r for r in _csv(out) if r["converged"] == "1"]
    r = rows[len(rows) // 2]
    i = src.nearest(float(r["x"]), float(r["y"]))
    assert (src.x[i], src.y[i]) == (float(r["x"]), float(r["y"]))
    hist = src.history(i, "u")
    np.testing.assert_allclose(hist, [0.0, float(r["u"])], atol=5e-7)    # the CSV's 6 decimals
    assert abs(hist[1] - 3.4) < 0.05 and src.values(0, "status")[i] == 0 and src.values(0, "zncc")[i] == 1.0


@pytest.mark.browser
def test_strains_in_the_specimen_frame_in_a_browser(browser, dic_sim, dic_run):
    """The specimen's x axis drawn on the map at about 30 degrees to the image's rows: the map turns to the
    specimen's frame, and its exx and exy in the tension state are the simulated plate strain (truth.npz,
    Green-Lagrange in the plate's e1, e2) resolved along that axis: the angle is where the simulator's own
    lens puts the line's two ends on the plate, y = z x x with z towards the cameras (-n)."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    from scanners.sim.dic import load_dic_truth, truth_at_pixels
    from stereodic.workspace.server import start
    d = browser
    ws = start([dic_run, dic_sim], background=True)
    try:
        d.get(ws.url + "?path=" + urllib.parse.quote(str(dic_run)))
        _wait(lambda: _plot(d, "field"), 60)
        handle = d.find_element(By.CSS_SELECTOR, "#state [role=slider]")
        handle.click()
        handle.send_keys(Keys.END)
        _wait(lambda: "tension" in (_plot(d, "field", "layout") or {}).get("title", {}).get("text", ""))
        rig_exx = np.nanmedian(_cells(d))
        d.find_element(By.CSS_SELECTOR, "#tool input[value=x-axis]").click()
        _wait(lambda: (_plot(d, "field", "layout") or {}).get("dragmode") == "drawline")
        _draw(d, "field", [(60, 130), (160, 72.26)])
        _wait(lambda: "frame: specimen" in (_plot(d, "field", "layout") or {}).get("title", {}).get("text", ""), 60)
        ends = [float(v) for v in d.find_element(By.ID, "x-axis").get_attribute("value").split(",")]
        exx = np.nanmedian(_cells(d))
        d.find_element(By.ID, "quantity").click()
        options = ".dash-dropdown-option"
        _wait(lambda: [o for o in d.find_elements(By.CSS_SELECTOR, options) if o.text == "exy"])[0].click()
        _wait(lambda: (_plot(d, "field", "layout") or {}).get("title", {}).get("text", "").startswith("exy"), 30)
        exy = np.nanmedian(_cells(d))
    finally:
        ws.stop()
    truth = truth_at_pixels(load_dic_truth(dic_sim), np.array([ends[:2], ends[2:], ((ends[0] + ends[2]) / 2,
                                                                                  (ends[1] + ends[3]) / 2)]))
    dx, dy = truth["material"][1] - truth["material"][0]
    c, s = np.array([dx, dy]) / np.hypot(dx, dy)          # the axis in the plate's (e1, e2)
    Exx, Eyy, Exy = (truth[k][2, 2] for k in ("exx", "eyy", "exy"))
    want_exx = 1e6 * (c * c * Exx + 2 * c * s * Exy + s * s * Eyy)
    want_exy = 1e6 * (c * s * (Exx - Eyy) + (s * s - c * c) * Exy)      # y = (s, -c): z x x with z = -n
    assert abs(np.degrees(np.arctan2(s, c))) > 20              # the axis is well off the plate's e1
    assert abs(exx - want_exx) < 200 and abs(exy - want_exy) < 200, (exx, want_exx, exy, want_exy)
    assert abs(rig_exx - 1e6 * Exx) < 200 and abs(rig_exx - exx) > 2000   # the rig's frame: along e1


def _cells(driver):
    """The field's cell values as plotted (the heat map's z), flattened."""
    values = driver.execute_script(
        "var z = document.querySelector('#field .js-plotly-plot')._fullData[0].z;"
        "var out = []; for (var i = 0; i < z.length; i++) for (var j = 0; j < z[i].length; j++) "
        "out.push(isFinite(z[i][j]) ? z[i][j] : null); return out;")
    return np.array([np.nan if v is None else v for v in values], np.float64)


def _start_and_wait(d, out, step="8", options=""):
    """The set-up page's output folder, step and further options typed, the run started and followed to
    its end; returns the command shown."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys
    for field_id, value in (("setup-output", str(out)), ("setup-step", step), ("setup-options", options)):
        field = d.find_element(By.ID, field_id)
        field.send_keys(Keys.CONTROL, "a")
        field.send_keys(value or Keys.DELETE, Keys.ENTER)
    d.find_element(By.ID, "start").click()
    _wait(lambda: "stereodic dic" in d.find_element(By.ID, "command").text, 30)
    _wait(lambda: d.find_elements(By.ID, "open-results") or "stopped" in d.find_element(By.ID, "progress").text,
          240, 1.0)
    assert d.find_elements(By.ID, "open-results"), d.find_element(By.ID, "progress").text
    return d.find_element(By.ID, "command").text


def _text(d, element_id):
    """An element's text, "" while it is not there (or the page is being replaced)."""
    from selenium.common.exceptions import WebDriverException
    from selenium.webdriver.common.by import By
    try:
        return d.find_element(By.ID, element_id).text
    except WebDriverException:
        return ""


def _use_images(d, left, right):
    """The left and right images typed on the set-up page (a pattern or a video each), the page reloaded."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys
    for field_id, value in (("setup-left", left), ("setup-right", right)):
        field = d.find_element(By.ID, field_id)
        field.send_keys(Keys.CONTROL, "a")
        field.send_keys(value)
    d.find_element(By.ID, "use-images").click()
    _wait(lambda: f"{left} --right" in _text(d, "setup-about"), 60)
    _wait(lambda: _plot(d, "noise"), 90)


def _mean_displacement(csv_path, state):
    rows = [r for r in _csv(csv_path) if r["state"] == str(state) and r["converged"] == "1"]
    return len(rows), np.array([[float(r[k]) for k in ("dX", "dY", "dZ")] for r in rows]).mean(0)


@pytest.mark.browser
def test_set_up_from_patterns_and_from_videos(browser, dic_sim, tmp_path):
    """A folder whose images are named by two patterns (images/left_*.png, images/right_*.png) and two
    lossless videos of the same frames (video/left.avi, video/right.avi): each typed on the set-up page,
    a region drawn, the run started. The pattern run measures the simulated rigid translation of state 1
    (0.6, -0.4, 1.2) mm; the video run gives the same numbers as the pattern run (the same pixels)."""
    import cv2
    from selenium.webdriver.common.by import By

    from calib.imageio import read_gray
    from stereodic.workspace.server import start
    d = browser
    lab = tmp_path / "lab"
    (lab / "images").mkdir(parents=True)
    (lab / "video").mkdir()
    shutil.copy(dic_sim / "rig.npz", lab / "rig.npz")
    for cam, side in (("cam0", "left"), ("cam1", "right")):
        video = cv2.VideoWriter(str(lab / "video" / f"{side}.avi"), cv2.VideoWriter_fourcc(*"FFV1"), 10, (240, 192),
                                isColor=False)
        for k in range(2):                              # the reference and the translation: a short run
            shutil.copy(dic_sim / f"s{k:03d}" / f"{cam}.png", lab / "images" / f"{side}_{k}.png")
            video.write(read_gray(dic_sim / f"s{k:03d}" / f"{cam}.png"))
        video.release()
    ws = start([lab], background=True)
    polygon = [(70, 60), (170, 60), (170, 130), (70, 130)]
    try:
        d.get(ws.url)
        _wait(lambda: d.find_elements(By.ID, "use-images"), 60)        # no pairs, no dataset: name the images
        assert "give the left and right" in d.find_element(By.ID, "setup-about").text
        runs = {}
        for kind, left, right in (("patterns", "images/left_*.png", "images/right_*.png"),
                                  ("videos", "video/left.avi", "video/right.avi")):
            _use_images(d, left, right)
            assert d.find_element(By.ID, "setup-about").text.startswith("2 states (--left ")
            source = _plot(d, "ref-image", "layout")["images"][0]["source"]
            assert urllib.parse.unquote(source).endswith("left_0.png" if kind == "patterns" else "left.avi::0")
            status, body, _ = _get(ws.url.rstrip("/") + source)          # the reference image, a video's frame too
            assert status == 200 and body.startswith("\x89PNG")
            d.find_element(By.ID, "clear-region").click()
            _wait(lambda: not (_plot(d, "ref-image", "layout") or {}).get("shapes"))
            _draw(d, "ref-image", polygon, closed=True)
            _wait(lambda: (_plot(d, "ref-image", "layout") or {}).get("shapes"))
            runs[kind] = lab / f"run-{kind}"
            command = _start_and_wait(d, runs[kind], step="10", options="--no-plot")
            assert f"--left {lab / left}" in command.replace("'", "") and f"--right {lab / right}" in \
                command.replace("'", "")
            record = json.loads((runs[kind] / "workspace.json").read_text())
            assert record["images"] == {"left": str(lab / left), "right": str(lab / right)}
            assert command.rstrip().endswith("--no-vtk --no-plot") and not (runs[kind] / "maps").exists()
            d.save_screenshot(str(tmp_path / f"setup-{kind}.png"))
        d.find_element(By.ID, "open-results").click()                  # the video run's results over its frame 0
        _wait(lambda: _plot(d, "field", "layout"), 60)
        assert urllib.parse.unquote(_plot(d, "field", "layout")["images"][0]["source"]).endswith("left.avi::0")
    finally:
        ws.stop()
    count, mean = _mean_displacement(runs["patterns"] / "dic.csv", 1)
    assert count > 30 and np.abs(mean - [0.6, -0.4, 1.2]).max() < 0.01, mean
    a, b = _csv(runs["patterns"] / "dic.csv"), _csv(runs["videos"] / "dic.csv")
    assert len(a) == len(b) and all(ra["dX"] == rb["dX"] and ra["exx"] == rb["exx"] for ra, rb in zip(a, b))


@pytest.mark.browser
def test_rig_from_another_programs_calibration(browser, dic_sim, tmp_path):
    """A folder of image pairs and an OpenCV stereo calibration (stereo_calib's M1 D1 M2 D2 R T, no image
    size), no rig: the page finds the file and its format, `stereodic import` (shown, with --size from the
    images) makes the rig, whose baseline is the file's |T|, and the page goes on to the set-up."""
    import cv2
    from selenium.webdriver.common.by import By

    from stereodic.stereo.rig import load_rig
    from stereodic.workspace.server import start
    d = browser
    folder = _image_pairs(dic_sim, tmp_path / "lab")
    phi = np.arctan2(-120.0, 400.0)                  # the right camera 120 mm to the right, turned to the left's target
    R = np.array([[np.cos(phi), 0, -np.sin(phi)], [0, 1, 0], [np.sin(phi), 0, np.cos(phi)]])     # R_y(-phi)
    T = -R @ np.array([120.0, 1.5, -4.0])
    K = np.array([[480.0, 0, 119.5], [0, 480.0, 95.5], [0, 0, 1]])
    fs = cv2.FileStorage(str(folder / "stereo.yml"), cv2.FILE_STORAGE_WRITE)
    for key, value in (("M1", K), ("D1", np.zeros((1, 5))), ("M2", K), ("D2", np.array([[-0.05, 0.01, 0, 0, 0]])),
                       ("R", R), ("T", T.reshape(3, 1))):
        fs.write(key, value)
    fs.release()
    ws = start([folder], background=True)
    try:
        d.get(ws.url)
        _wait(lambda: d.find_elements(By.ID, "import-rig"), 60)
        assert "(opencv)" in d.find_element(By.ID, "import-file").text
        assert d.find_element(By.ID, "import-size").get_attribute("value") == "240x192"
        d.find_element(By.ID, "import-rig").click()
        _wait(lambda: d.find_elements(By.ID, "open-setup") or d.find_element(By.ID, "rig-message").text, 120)
        assert d.find_elements(By.ID, "open-setup"), d.find_element(By.ID, "rig-message").text
        line = d.find_element(By.ID, "rig-command").text.splitlines()[0]
        assert line == f"stereodic import {folder / 'stereo.yml'} -o {folder / 'rig.npz'} --size 240x192"
        rig = load_rig(folder / "rig.npz")
        assert abs(np.linalg.norm(rig.baseline) - np.linalg.norm(T)) < 1e-6 * np.linalg.norm(T)
        d.find_element(By.ID, "open-setup").click()
        _wait(lambda: _plot(d, "noise"), 90)
        assert "3 states" in d.find_element(By.ID, "setup-about").text
        d.save_screenshot(str(tmp_path / "imported.png"))
    finally:
        ws.stop()


def test_typed_images_stay_in_the_served_folders(tmp_path):
    """A pattern or video typed on the set-up page is checked file by file before any is read: one that
    reaches outside the served folders (through `..`, an absolute path, a side-by-side half, a frame
    reference) is refused with a line naming it; one inside is made absolute."""
    from calib.errors import InputError
    from stereodic.workspace.access import Access
    from stereodic.workspace.setup_view import image_pattern
    served, outside = tmp_path / "served", tmp_path / "outside"
    (served / "images").mkdir(parents=True)
    outside.mkdir()
    for folder in (served / "images", outside):
        (folder / "left_0.png").write_bytes(b"")
    (outside / "stereo.avi").write_bytes(b"")
    access = Access([served])
    assert image_pattern(served, "images/left_*.png", access, "left") == str(served / "images" / "left_*.png")
    for bad in ("../outside/left_*.png", str(outside / "left_*.png"), "images/../../outside/*.png",
                "../outside/stereo.avi:left", str(outside / "stereo.avi")):
        with pytest.raises(InputError, match="outside the folders"):
            image_pattern(served, bad, access, "left")
    with pytest.raises(InputError, match="outside the folders"):
        access.resolve(f"{outside / 'stereo.avi'}::0")
    with pytest.raises(InputError, match="right images"):
        image_pattern(served, " ", access, "right")


def test_area_gauge_in_the_specimen_frame_is_the_gauge_commands(dic_run, tmp_path):
    """An area drawn on the page with the specimen's x axis set: its mean exx per state is what `stereodic
    gauge --frame specimen --x-axis` writes for the same polygon; the map's median over the area agrees
    (the map and the gauges refit the strains alike), and the axis turns exx away from the rig frame's."""
    from matplotlib.path import Path as MPath

    from stereodic.workspace.dic_view import gauge_curve, source
    corners = [(60.0, 50.0), (170.0, 55.0), (165.0, 140.0), (65.0, 135.0)]
    axis = (60.0, 130.0, 160.0, 72.26)
    shape = {"type": "path", "path": "M" + "L".join(f"{x},{y}" for x, y in corners) + "Z"}
    _, table, _ = gauge_curve(str(dic_run), shape, "area", "exx", "specimen", axis)
    page = np.array([row[2] for row in table["rows"]])
    polygon = ";".join(f"{x},{y}" for x, y in corners)
    assert main(["gauge", str(dic_run), "--area", f"A1={polygon}", "--frame", "specimen", "--x-axis",
                 ",".join(map(str, axis)), "-o", str(tmp_path / "g")]) == 0
    want = np.array([float(r["exx_mean"]) for r in _csv(tmp_path / "g" / "areas.csv")])
    np.testing.assert_allclose(page, want, rtol=0, atol=2e-9)                 # the CSV's 9 decimals
    spec, rig = source(dic_run, "specimen", axis), source(dic_run, "rig")
    inside = MPath(corners).contains_points(np.column_stack([spec.x, spec.y]))
    assert abs(np.nanmedian(spec.values(2, "exx")[inside]) - 1e6 * want[2]) < 150
    assert abs(np.nanmedian(rig.values(2, "exx")[inside]) - 1e6 * want[2]) > 2000
