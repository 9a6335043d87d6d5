"""PLY files (io/ply.py on plyfile, through PointCloud): header, size against the vertex count, rows read, finite
positions; the writer streamed in chunks."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import panorecon.io.ply
from panorecon.geometry import PointCloud
from panorecon.io import PanoreconInputError
from panorecon.io.ply import read_ply


@pytest.fixture(scope="module")
def ply_bytes(tmp_path_factory):
    d = tmp_path_factory.mktemp("ply")
    rng = np.random.default_rng(0)
    PointCloud(rng.normal(size=(500, 3)), rng.random((500, 3)), view_id=np.arange(500) % 7).save_ply(d / "a.ply")
    return (d / "a.ply").read_bytes()


def test_round_trip_keeps_points_colours_and_view_ids(tmp_path, ply_bytes):
    (tmp_path / "a.ply").write_bytes(ply_bytes)
    pc = PointCloud.load_ply(tmp_path / "a.ply")
    assert len(pc) == 500 and len(read_ply(tmp_path / "a.ply")["x"]) == 500
    np.testing.assert_array_equal(pc.view_id, np.arange(500) % 7)


def test_uchar_colours_are_written_as_bytes_and_read_back(tmp_path):
    rng = np.random.default_rng(1)
    pc = PointCloud(rng.normal(size=(50, 3)), rng.random((50, 3)))
    pc.save_ply(tmp_path / "u.ply", uchar_rgb=True)
    raw = (tmp_path / "u.ply").read_bytes()
    assert b"property float x\n" in raw and b"property uchar red\n" in raw and b"property float red" not in raw
    back = PointCloud.load_ply(tmp_path / "u.ply")
    np.testing.assert_array_equal(back.xyz, pc.xyz)
    np.testing.assert_allclose(back.rgb, np.round(pc.rgb * 255) / 255, atol=1e-7)


@given(frac=st.floats(min_value=0.0, max_value=0.999))
def test_a_cut_off_ply_is_refused_not_read_as_points_at_the_origin(tmp_path_factory, ply_bytes, frac):
    path = tmp_path_factory.mktemp("cut") / "cut.ply"
    path.write_bytes(ply_bytes[: int(len(ply_bytes) * frac)])
    with pytest.raises(PanoreconInputError, match="cut.ply"):
        PointCloud.load_ply(path)


def test_extra_bytes_nan_positions_and_non_ply_are_refused(tmp_path, ply_bytes, capfd):
    (tmp_path / "long.ply").write_bytes(ply_bytes + b"\0" * 15)
    (tmp_path / "text.ply").write_text("hello")
    (tmp_path / "zero.ply").write_bytes(ply_bytes.replace(b"element vertex 500", b"element vertex 0"))
    PointCloud(np.ones((4, 3)), np.zeros((4, 3))).save_ply(tmp_path / "nan.ply")
    raw = bytearray((tmp_path / "nan.ply").read_bytes())
    body = raw.index(b"end_header\n") + len(b"end_header\n")
    raw[body : body + 4] = np.float32(np.nan).tobytes()
    (tmp_path / "nan.ply").write_bytes(bytes(raw))
    capfd.readouterr()
    for name, needle in [
        ("long.ply", "expected"),
        ("text.ply", "not a PLY"),
        ("zero.ply", "no vertices"),
        ("nan.ply", "NaN or Inf"),
        ("missing.ply", "no such file"),
    ]:
        with pytest.raises(PanoreconInputError, match=needle) as e:
            PointCloud.load_ply(tmp_path / name)
        assert name in str(e.value)
    assert capfd.readouterr().err == ""  # Open3D's own "Read PLY failed" does not reach the terminal


def test_an_ascii_ply_from_elsewhere_is_read(tmp_path):
    (tmp_path / "a.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
        "property float z\nend_header\n0 0 1\n1 2 3\n"
    )
    pc = PointCloud.load_ply(tmp_path / "a.ply")
    np.testing.assert_allclose(pc.xyz, [[0, 0, 1], [1, 2, 3]])


@pytest.mark.parametrize(
    "text, needle",
    [
        (
            "element vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 1\n1 2 3\n",
            "2 data lines",
        ),
        ("element vertex 2\nproperty float x\nend_header\n1\n2\n", "no x, y, z"),
    ],
)
def test_a_short_or_positionless_ascii_ply_is_refused(tmp_path, text, needle):
    (tmp_path / "a.ply").write_text("ply\nformat ascii 1.0\n" + text)
    with pytest.raises(PanoreconInputError, match=needle):
        PointCloud.load_ply(tmp_path / "a.ply")


def test_streamed_ply_equals_the_cloud(tmp_path, monkeypatch):
    monkeypatch.setattr(panorecon.io.ply, "PLY_CHUNK", 7)  # many chunks, the last one short
    rng = np.random.default_rng(1)
    pc = PointCloud(rng.normal(size=(50, 3)), rng.random((50, 3)), view_id=rng.integers(0, 9, 50))
    pc.save_ply(tmp_path / "c.ply")
    back = PointCloud.load_ply(tmp_path / "c.ply")
    np.testing.assert_array_equal(back.xyz, pc.xyz)
    np.testing.assert_array_equal(back.rgb, pc.rgb)
    np.testing.assert_array_equal(back.view_id, pc.view_id)
