import numpy as np
import pytest

from panorecon.io import PanoreconInputError, atomic_write, read_image, write_image, write_json
from panorecon.io.files import check_erp_shape


def test_not_two_to_one_is_refused(tmp_path):
    write_image(tmp_path / "sq.png", np.zeros((16, 16, 3), np.uint8))
    with pytest.raises(PanoreconInputError, match=r"sq.png: size 16x16 is not an equirectangular panorama"):
        read_image(tmp_path / "sq.png", erp=True)


def test_truncated_and_empty_files_are_refused(tmp_path):
    write_image(tmp_path / "ok.png", np.zeros((8, 16, 3), np.uint8))
    data = (tmp_path / "ok.png").read_bytes()
    (tmp_path / "cut.png").write_bytes(data[: len(data) // 2])
    (tmp_path / "empty.png").write_bytes(b"")
    for name in ("cut.png", "empty.png"):
        with pytest.raises(PanoreconInputError, match=name):
            read_image(tmp_path / name, erp=True)
    with pytest.raises(PanoreconInputError, match="no such file"):
        read_image(tmp_path / "missing.png")


def test_absurd_width_is_refused():
    with pytest.raises(PanoreconInputError, match="larger than the supported 16384"):
        check_erp_shape((10000, 20000), "big.png")


def test_rgb_order_round_trip(tmp_path):
    img = np.zeros((4, 8, 3), np.uint8)
    img[..., 0] = 200  # red
    write_image(tmp_path / "r.png", img)
    np.testing.assert_array_equal(read_image(tmp_path / "r.png", erp=True), img)


def test_atomic_write_leaves_old_file_on_failure(tmp_path):
    target = tmp_path / "result.json"
    write_json(target, {"a": 1})
    with pytest.raises(RuntimeError):
        with atomic_write(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("interrupted")
    assert target.read_text().strip().startswith("{") and '"a": 1' in target.read_text()
    assert [p.name for p in tmp_path.iterdir()] == ["result.json"]


def test_json_refuses_nan(tmp_path):
    with pytest.raises(ValueError):
        write_json(tmp_path / "x.json", {"psnr": float("nan")})
    assert not (tmp_path / "x.json").exists()


@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_atomic_write_gives_the_users_normal_permissions(tmp_path, umask):
    import os

    from panorecon.geometry import PointCloud

    old = os.umask(umask)
    try:
        write_json(tmp_path / "a.json", {"a": 1})
        write_image(tmp_path / "b.png", np.zeros((4, 8, 3), np.uint8))
        PointCloud(np.ones((3, 3)), np.zeros((3, 3))).save_ply(tmp_path / "c.ply")
        with open(tmp_path / "ref", "w"):  # what open() gives: the user's normal mode
            pass
    finally:
        os.umask(old)
    want = 0o666 & ~umask
    assert (os.stat(tmp_path / "ref").st_mode & 0o777) == want
    for name in ("a.json", "b.png", "c.ply"):
        assert (os.stat(tmp_path / name).st_mode & 0o777) == want, name


def test_a_broken_image_is_one_error_and_libpng_stays_quiet(tmp_path, capfd):
    write_image(tmp_path / "ok.png", (np.arange(64 * 128 * 3) % 251).astype(np.uint8).reshape(64, 128, 3))
    data = (tmp_path / "ok.png").read_bytes()
    (tmp_path / "cut.png").write_bytes(data[: len(data) * 2 // 3])
    capfd.readouterr()
    with pytest.raises(PanoreconInputError, match="cut.png"):
        read_image(tmp_path / "cut.png", erp=True)
    out, err = capfd.readouterr()
    assert out == "" and err == ""  # libpng's own "libpng error: ..." is not shown at the file-descriptor level
