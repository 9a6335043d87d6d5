"""`panorecon view`: what a run folder shows, the Gaussians' covariances, and the page in a real browser."""

import json
import math
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
import torch
from PIL import Image

from panorecon.cli import main
from panorecon.geometry import PointCloud, centred_camera
from panorecon.io import PanoreconInputError
from panorecon.splat.model import GaussianModel
from panorecon.splat.ply import save_ply
from panorecon.viewer import _wxyz, collect, gaussian_arrays, serve


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory):
    d = tmp_path_factory.mktemp("run")
    rng = np.random.default_rng(0)
    n = 300
    quats = torch.tensor(rng.normal(size=(n, 4)), dtype=torch.float32)
    model = GaussianModel(
        torch.tensor(rng.normal(size=(n, 3)) * 0.5, dtype=torch.float32),
        quats,
        torch.tensor(np.log(rng.uniform(0.05, 0.2, (n, 3))), dtype=torch.float32),
        torch.full((n,), 3.0),
        torch.tensor(rng.normal(size=(n, 1, 3)), dtype=torch.float32),
        torch.zeros(n, 3, 3),
    )
    save_ply(model, d / "point_cloud.ply")
    PointCloud(rng.normal(size=(400, 3)), rng.uniform(size=(400, 3))).save_ply(d / "fibonacci_cloud.ply")
    (d / "fibonacci_report.json").write_text(
        json.dumps({"source": "fibonacci", "views": 20, "fov_deg": 89.4, "view_size": 64})
    )
    cams = [centred_camera(np.array([1.0, 0, 0]), 32, 60.0), centred_camera(np.array([0, 1.0, 0.2]), 32, 60.0)]
    (d / "cameras.json").write_text(
        json.dumps(
            {
                "pseudo-label": [
                    {"viewmat": c.viewmat.tolist(), "K": c.K.tolist(), "width": 32, "height": 32} for c in cams
                ],
                "held-out": [{"viewmat": cams[0].viewmat.tolist(), "K": cams[0].K.tolist(), "width": 32, "height": 32}],
            }
        )
    )
    return d, model


def test_run_folder_items(run_folder):
    d, _ = run_folder
    items = collect(d)
    assert [p.name for p in items.gaussians] == ["point_cloud.ply"]
    assert [p.name for p in items.clouds] == ["fibonacci_cloud.ply"]
    assert {k: len(v) for k, v in items.frustums.items()} == {"fibonacci views": 20, "pseudo-label": 2, "held-out": 1}
    f = items.frustums["pseudo-label"][0]
    assert f.aspect == 1.0 and math.isclose(f.fov_y, math.radians(60.0), rel_tol=1e-9)
    assert collect(d / "fibonacci_cloud.ply").clouds and collect(d / "point_cloud.ply").gaussians


def test_bad_paths_say_what_was_expected(tmp_path, capsys):
    with pytest.raises(PanoreconInputError, match="no such file"):
        collect(tmp_path / "missing")
    with pytest.raises(PanoreconInputError, match="no .ply"):
        collect(tmp_path)
    (tmp_path / "x.txt").write_text("x")
    assert main(["view", str(tmp_path / "x.txt")]) == 2
    assert "expected a .ply" in capsys.readouterr().err


def test_gaussian_arrays_match_a_per_gaussian_loop(run_folder):
    d, model = run_folder
    a = gaussian_arrays(d / "point_cloud.ply")
    for i in range(0, len(model), 37):
        w, x, y, z = (model.quats[i] / model.quats[i].norm()).detach().tolist()
        R = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
            ]
        )
        cov = R @ np.diag(np.exp(model.log_scales[i].detach().double().numpy()) ** 2) @ R.T
        np.testing.assert_allclose(a["covariances"][i], cov, rtol=1e-4, atol=1e-8)
        rgb = np.clip(0.5 + 0.28209479177387814 * model.sh0[i, 0].detach().numpy(), 0, 1)
        np.testing.assert_allclose(a["rgbs"][i], rgb, atol=1e-6)
        assert math.isclose(a["opacities"][i, 0], 1 / (1 + math.exp(-3.0)), rel_tol=1e-6)
    assert np.all(np.linalg.eigvalsh(a["covariances"].astype(np.float64)) > 0)


def test_frustum_rotation_is_the_camera_to_world_rotation():
    c = centred_camera(np.array([0.3, -1.0, 0.5]), 16, 60.0)
    w, x, y, z = _wxyz(c.rotation_c2w)
    R = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    np.testing.assert_allclose(R[:, 2], c.forward, atol=1e-9)  # viser frustums look along their +z (OpenCV)


def test_cli_prints_the_url_and_serves_the_page(run_folder):
    import urllib.request

    d, _ = run_folder
    port = _free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "panorecon.cli", "view", str(d), "--port", str(port), "--host", "127.0.0.1"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        lines = []
        while not lines or not lines[-1].startswith("panorecon view:"):  # viser prints its own banner first
            lines.append(proc.stdout.readline())
            assert lines[-1], lines  # EOF: the command died
        assert f"http://127.0.0.1:{port}" in lines[-1], lines
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/", timeout=30) as r:
            assert r.status == 200 and b"<html" in r.read().lower()
    finally:
        proc.terminate()
        proc.wait(30)


def test_viewer_page_connects_and_draws(run_folder, browser, tmp_path):
    d, _ = run_folder
    server = serve(d, _free_port(), "127.0.0.1", point_size=0.1)
    try:
        page = browser.new_page(viewport={"width": 800, "height": 600})
        page.goto(f"http://127.0.0.1:{server.get_port()}/")
        page.wait_for_selector("canvas", timeout=60_000)
        t0 = time.time()
        while not server.get_clients() and time.time() - t0 < 60:
            time.sleep(0.5)
        assert len(server.get_clients()) == 1  # the page's websocket reached this server
        time.sleep(5)  # scene messages and a few frames of software WebGL
        shot = tmp_path / "viewer.png"
        page.locator("canvas").first.screenshot(path=str(shot))
        a = np.asarray(Image.open(shot).convert("RGB")).astype(float)
        # not blank: many pixels differ from the background (the corner)
        assert (np.abs(a - a[2, 2]).sum(-1) > 40).mean() > 0.01, a.std()
        page.close()
    finally:
        server.stop()
