"""Our 3DGS PLY against the other side's own code: ``GaussianModel.save_ply`` / ``load_ply`` of the original 3DGS
(graphdeco-inria/gaussian-splatting, ``scene/gaussian_model.py``), re-stated below step for step in NumPy and plyfile
(its class needs CUDA). A file written their way reads with ours, ours reads their way, parameter for parameter,
and both ways write the same bytes."""

import numpy as np
import pytest
import torch
from plyfile import PlyData, PlyElement

from panorecon.splat.model import GaussianModel
from panorecon.splat.ply import load_ply, save_ply


def _their_parameters(n: int, sh_degree: int, seed: int = 0) -> dict:
    """Their parameter shapes: _xyz [N,3], _features_dc [N,1,3], _features_rest [N,(d+1)^2-1,3], _opacity [N,1],
    _scaling [N,3], _rotation [N,4] (wxyz), float32."""
    rng = np.random.default_rng(seed)
    k = (sh_degree + 1) ** 2 - 1
    shapes = {"xyz": (n, 3), "f_dc": (n, 1, 3), "f_rest": (n, k, 3), "opacity": (n, 1), "scaling": (n, 3)}
    params = {name: rng.normal(size=shape).astype(np.float32) for name, shape in shapes.items()}
    params["rotation"] = rng.normal(size=(n, 4)).astype(np.float32)
    return params


def _construct_list_of_attributes(p: dict) -> list[str]:
    names = ["x", "y", "z", "nx", "ny", "nz"]
    names += [f"f_dc_{i}" for i in range(p["f_dc"].shape[1] * p["f_dc"].shape[2])]
    names += [f"f_rest_{i}" for i in range(p["f_rest"].shape[1] * p["f_rest"].shape[2])]
    names.append("opacity")
    names += [f"scale_{i}" for i in range(p["scaling"].shape[1])]
    names += [f"rot_{i}" for i in range(p["rotation"].shape[1])]
    return names


def _their_save_ply(p: dict, path) -> None:
    xyz = p["xyz"]
    normals = np.zeros_like(xyz)
    f_dc = p["f_dc"].transpose(0, 2, 1).reshape(len(xyz), -1)  # .transpose(1, 2).flatten(start_dim=1)
    f_rest = p["f_rest"].transpose(0, 2, 1).reshape(len(xyz), -1)
    dtype_full = [(attribute, "f4") for attribute in _construct_list_of_attributes(p)]
    elements = np.empty(xyz.shape[0], dtype=dtype_full)
    attributes = np.concatenate((xyz, normals, f_dc, f_rest, p["opacity"], p["scaling"], p["rotation"]), axis=1)
    elements[:] = list(map(tuple, attributes))
    PlyData([PlyElement.describe(elements, "vertex")]).write(str(path))


def _their_load_ply(path, max_sh_degree: int) -> dict:
    plydata = PlyData.read(str(path))
    v = plydata.elements[0]
    xyz = np.stack((np.asarray(v["x"]), np.asarray(v["y"]), np.asarray(v["z"])), axis=1)
    opacities = np.asarray(v["opacity"])[..., np.newaxis]
    features_dc = np.zeros((xyz.shape[0], 3, 1))
    for c in range(3):
        features_dc[:, c, 0] = np.asarray(v[f"f_dc_{c}"])
    extra = sorted((p.name for p in v.properties if p.name.startswith("f_rest_")), key=lambda x: int(x.split("_")[-1]))
    assert len(extra) == 3 * (max_sh_degree + 1) ** 2 - 3
    features_extra = np.stack([np.asarray(v[name]) for name in extra], 1) if extra else np.zeros((len(xyz), 0))
    features_extra = features_extra.reshape((xyz.shape[0], 3, (max_sh_degree + 1) ** 2 - 1))

    def by_index(prefix):
        names = sorted((p.name for p in v.properties if p.name.startswith(prefix)), key=lambda x: int(x.split("_")[-1]))
        return np.stack([np.asarray(v[name]) for name in names], 1)

    return {
        "xyz": xyz,
        "f_dc": features_dc.transpose(0, 2, 1),  # their tensors transposed back: [N, 1, 3]
        "f_rest": features_extra.transpose(0, 2, 1),  # [N, (d+1)^2-1, 3]
        "opacity": opacities,
        "scaling": by_index("scale_"),
        "rotation": by_index("rot"),
    }


def _as_ours(p: dict) -> dict:
    """Their parameters under our names and shapes."""
    return {
        "means": p["xyz"],
        "quats": p["rotation"],
        "log_scales": p["scaling"],
        "logit_opacities": p["opacity"][:, 0],
        "sh0": p["f_dc"],
        "shN": p["f_rest"],
    }


@pytest.mark.parametrize("sh_degree", [0, 3])
def test_a_file_written_by_the_original_reads_with_ours(tmp_path, sh_degree):
    theirs = _their_parameters(40, sh_degree)
    _their_save_ply(theirs, tmp_path / "theirs.ply")
    model = load_ply(tmp_path / "theirs.ply")
    for name, want in _as_ours(theirs).items():
        got = getattr(model, name).detach()
        assert got.dtype == torch.float32, name
        np.testing.assert_array_equal(got.numpy(), want, err_msg=name)


@pytest.mark.parametrize("sh_degree", [0, 3])
def test_our_file_reads_with_the_original_and_has_its_bytes(tmp_path, sh_degree):
    theirs = _their_parameters(40, sh_degree, seed=1)
    ours = _as_ours(theirs)
    model = GaussianModel(*(torch.from_numpy(ours[k].copy()) for k in ours))
    save_ply(model, tmp_path / "ours.ply")
    back = _their_load_ply(tmp_path / "ours.ply", sh_degree)
    for name, want in theirs.items():
        np.testing.assert_array_equal(back[name].astype(np.float32), want, err_msg=name)
    _their_save_ply(theirs, tmp_path / "theirs.ply")
    assert (tmp_path / "ours.ply").read_bytes() == (tmp_path / "theirs.ply").read_bytes()


def test_properties_are_found_by_name_as_the_original_does(tmp_path):
    """The original's reader looks properties up by name; so does ours: a writer's other order, no normals and
    an extra property read the same."""
    theirs = _their_parameters(10, 1, seed=2)
    _their_save_ply(theirs, tmp_path / "theirs.ply")
    v = PlyData.read(str(tmp_path / "theirs.ply"))["vertex"].data
    names = [n for n in v.dtype.names if n not in ("nx", "ny", "nz")][::-1]
    shuffled = np.empty(len(v), dtype=[(n, "f4") for n in names] + [("filter_3d", "f4")])
    for n in names:
        shuffled[n] = v[n]
    PlyData([PlyElement.describe(shuffled, "vertex")]).write(str(tmp_path / "shuffled.ply"))
    a, b = load_ply(tmp_path / "theirs.ply"), load_ply(tmp_path / "shuffled.ply")
    for pa, pb in zip(a.parameters(), b.parameters()):
        torch.testing.assert_close(pa, pb, rtol=0, atol=0)
