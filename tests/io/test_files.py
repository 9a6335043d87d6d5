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
