"""Seeded variants of the synthetic scenes (``bedroom@3``): deterministic, different per K, with exact truth, and
the plain names unchanged."""

import hashlib
import json

import numpy as np
import open3d as o3d
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from panorecon.geometry import erp_directions, fibonacci_directions
from panorecon.io import PanoreconInputError
from panorecon.scenes import list_scenes, load_scene
from panorecon.scenes import synthetic as S
from panorecon.scenes.catalog import SYNTHETIC_SCENES
from panorecon.scenes.variation import Draws, variant_rng

INDOOR = {"bedroom", "bathroom", "library", "exhibition-hall"}

# build_scene(name, 64) as computed with the code before variants existed: the sha256 of its rgb bytes, and of
# its distance the finite pixels' count, sum and sum of squares (float64). The base scenes must stay as they were
# (results computed before stay comparable). The colours are bit-identical on every machine; Open3D's ray caster
# rounds a hit's distance differently on another CPU (seen: the distance bytes' digest differs between two
# machines whose colours agree), so the distances are compared to 1e-6 relative.
BASE_SCENES = {
    "bedroom": (
        "89cc17b72bbfffe046af1b996111f2600880a136a595633ae87c79f92b77cfa6",
        (2048, 4022.516715168953, 8850.169024970724),
    ),
    "bathroom": (
        "5beb76ac1341b29bddf85fbd18c8aea0f37b16f0620e3d06cad69f184e1ad778",
        (2048, 3588.2643003463745, 6727.180465596426),
    ),
    "library": (
        "1ff19a5dd9f461686bbe9239dd193401623d09ae57451753e8208cd864153d3d",
        (2048, 6741.735495209694, 26784.362028746236),
    ),
    "exhibition-hall": (
        "49f23c2eeef4e23bff0d956429c3123cd7de100dc21d468a4e804be923a26e4d",
        (2048, 9178.075404882431, 54489.27552024733),
    ),
    "mountain": (
        "a3a59599a95015813425d965f7cdd4e616137fcfedfff41b6d2d8a2d2b68f18a",
        (1519, 239807.60549235344, 223965612.82575113),
    ),
    "grassland": (
        "87e2760cd7b222dc517f317b756544f7c2c88a3a7c3ef3101e73db6b1b755dbf",
        (1071, 15569.37375998497, 3007782.0949583976),
    ),
    "beach": (
        "f6b02afd8720ffddb5057e81e586cf63d893404f47855b0d5fd42e5966a04921",
        (1048, 5366.059239387512, 101625.51257451359),
    ),
    "city-plaza": (
        "87014dff25a7601a2e9ac95f4a9790bcf3674db5c35841ca7ba6f09328d3bead",
        (1312, 17415.39357972145, 660995.0505719341),
    ),
}


def _fresh(name, width=64):
    """build_scene with the world cache emptied first: the world is built again from its name."""
    S._WORLDS.clear()
    return S.build_scene(name, width)


@pytest.mark.parametrize("name", list(SYNTHETIC_SCENES))
def test_base_scene_is_bit_identical_to_before_variants(name):
    s = _fresh(name)
    rgb, (count, total, squares) = BASE_SCENES[name]
    assert hashlib.sha256(s.rgb.tobytes()).hexdigest() == rgb
    d = s.distance.astype(np.float64)
    d = d[np.isfinite(d)]
    assert d.size == count
    np.testing.assert_allclose([d.sum(), (d**2).sum()], [total, squares], rtol=1e-6)
    assert s.meta["variant"] is None and s.world.variant is None


@pytest.mark.parametrize("name", list(SYNTHETIC_SCENES))
def test_variant_is_deterministic_and_differs_from_other_k_and_the_base(name):
    a, b, other, base = _fresh(f"{name}@3"), _fresh(f"{name}@3"), _fresh(f"{name}@4"), _fresh(name)
    assert a.world is not b.world  # built twice, not read from the cache
    np.testing.assert_array_equal(a.rgb, b.rgb)
    np.testing.assert_array_equal(a.distance, b.distance)
    assert a.meta == b.meta and a.meta["variant"] == 3 and a.name == f"{name}@3"
    for c in (other, base):
        assert c.meta["params"] != a.meta["params"]
        assert not np.array_equal(c.rgb, a.rgb)
        assert not np.array_equal(c.distance, a.distance)
    assert json.loads(json.dumps(a.meta)) == a.meta  # results can record what was run
    assert set(a.meta["params"]) == set(base.meta["params"])  # the same parameters, drawn or at their defaults


def test_rooms_change_size_and_layout():
    params = [_fresh(f"bedroom@{k}").meta["params"] for k in (1, 2, 3)]
    for key in ("width_m", "depth_m", "height_m", "bed_y_m", "light", "floor"):
        assert len({json.dumps(p[key]) for p in params}) == 3, key


def _assert_truth(w, erp, origin):
    """The ERP's distances put every non-sky pixel on the scene's surface (checked against a ray caster built
    here from the world's mesh), sky exactly where the distance is infinite."""
    np.testing.assert_array_equal(erp.sky, np.isinf(erp.distance))
    h = erp.distance.shape[0]
    dirs = erp_directions(h, 2 * h)
    pts = origin + dirs[~erp.sky] * erp.distance[~erp.sky][:, None].astype(np.float64)
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(w.mesh()))
    gap = rc.compute_distance(o3d.core.Tensor(pts.astype(np.float32))).numpy()
    assert gap.max() < 1e-4 * max(1.0, float(erp.distance[~erp.sky].max()))


@pytest.mark.parametrize("name", ["bedroom@2", "library@5", "beach@2", "city-plaza@7"])
def test_variant_distance_is_the_true_surface_from_the_centre_and_off_centre(name):
    w = S.world(name)
    r = w.free_space_radius()
    assert r >= S.MIN_FREE_RADIUS
    _assert_truth(w, w.render_erp(24), np.zeros(3))
    p = np.array([0.7 * r, -0.4 * r, 0.2 * r])  # a held-out viewpoint inside the free space
    erp = w.render_erp(24, p)
    _assert_truth(w, erp, p)
    assert erp.distance.min() > 0.15


@pytest.mark.parametrize("name", list(SYNTHETIC_SCENES))
@settings(max_examples=2, deadline=None)
@given(k=st.integers(1, 10**9))
def test_any_variant_builds_with_room_around_the_eye(name, k):
    s = load_scene(f"{name}@{k}", 64)
    assert s.rgb.shape == (32, 64, 3) and s.distance.dtype == np.float32 and s.has_ground_truth
    np.testing.assert_array_equal(s.sky, np.isinf(s.distance))
    assert (not s.sky.any()) if name in INDOOR else (0.1 < s.sky.mean() < 0.7)
    assert s.world.free_space_radius() >= S.MIN_FREE_RADIUS
    _, dist, _ = s.world.cast(np.zeros(3), fibonacci_directions(2000))
    assert dist.min() > S.MIN_FREE_RADIUS  # nothing at the eye, in any direction
    assert s.rgb[~s.sky].std() > 10  # still textured
    json.dumps(s.meta)


@pytest.mark.parametrize(
    "bad, expected",
    [
        ("bedroom@0", "K an integer >= 1"),
        ("bedroom@x", "K an integer >= 1"),
        ("bedroom@03", "without leading zeros"),
        ("bedroom@1..3", "suite's scene list"),
        ("nosuch@2", "synthetic scenes"),
        ("photo.png@2", "synthetic scenes"),
        ("NAME@K", "synthetic scenes"),
    ],
)
def test_bad_variant_names_are_one_clear_line(bad, expected):
    with pytest.raises(PanoreconInputError, match=expected) as e:
        load_scene(bad, 64)
    assert repr(bad) in str(e.value) and "\n" not in str(e.value)


def test_scenes_list_has_one_line_for_all_variants():
    specs = list_scenes()
    variants = [s for s in specs if s.kind == "variant"]
    assert len(variants) == 1 and "@" in variants[0].name and "bedroom@1..10" in variants[0].description
    assert {s.name for s in specs if s.kind == "synthetic"} == set(SYNTHETIC_SCENES)
    with pytest.raises(PanoreconInputError, match="pattern"):
        variants[0].build(64)


def test_draws_at_defaults_return_them_unchanged_and_record_every_parameter():
    v, colour = Draws(), [0.1, 0.2, 0.3]
    assert v.uniform("a", 1.5, 0, 9) == 1.5 and v.integer("n", 4, 0, 9) == 4 and v.flag("f") is False
    assert v.color("c", colour) is colour
    assert v.params == {"a": 1.5, "n": 4, "f": False, "c": colour}
    with pytest.raises(ValueError, match="twice"):
        v.uniform("a", 1.5, 0, 9)


def test_drawn_parameters_stay_in_their_ranges():
    v = Draws(variant_rng("bedroom", 1))
    for i in range(200):
        assert 2.0 <= v.uniform(f"u{i}", 0.0, 2.0, 3.0) < 3.0
        assert 4 <= v.integer(f"n{i}", 0, 4, 6) <= 6
        c = v.color(f"c{i}", [0.9, 0.5, 0.1], 0.5)
        assert ((0 <= c) & (c <= 1)).all()
        d = v.direction(f"d{i}", np.array([0.0, 0.0, 1.0]), 20, 75)
        assert np.linalg.norm(d) == pytest.approx(1) and np.sin(np.radians(20)) <= d[2] <= np.sin(np.radians(75))
    assert {v.integer(f"m{i}", 0, 4, 6) for i in range(100)} == {4, 5, 6}


def test_variant_generator_depends_on_name_and_k_only():
    draw = lambda name, k: variant_rng(name, k).uniform(size=4)  # noqa: E731
    np.testing.assert_array_equal(draw("bedroom", 2), draw("bedroom", 2))
    assert not np.array_equal(draw("bedroom", 2), draw("bedroom", 3))
    assert not np.array_equal(draw("bedroom", 2), draw("bathroom", 2))


def test_a_draw_with_too_little_room_at_the_eye_is_drawn_again(monkeypatch):
    monkeypatch.setattr(S, "MIN_FREE_RADIUS", 0.82)  # between the bedroom variants' free radii (about 0.8 m)
    worlds = [S._draw_variant("bedroom", k, 7) for k in range(1, 7)]
    assert all(w.free_space_radius() >= 0.82 for w in worlds)
    assert any(w.redraws > 0 for w in worlds)
    monkeypatch.setattr(S, "MIN_FREE_RADIUS", 50.0)  # no room is that large
    with pytest.raises(RuntimeError, match="bedroom@1"):
        S._draw_variant("bedroom", 1, 7)
