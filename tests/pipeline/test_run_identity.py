"""Run identities that survive new options: a field added after the first committed tables declares the value at
which it behaves as before it existed, and a run that leaves it there keeps the identity it had."""

import dataclasses

import pytest

from panorecon import checks as C
from panorecon.checks import identity, opt
from panorecon.fusion import FusionOptions
from panorecon.pipeline import Row
from panorecon.splat.trainer import TrainConfig

# TrainConfig's fields when the committed tables 2-7 ran (benchmarks/tables/table2 ... table7): every run
# identity hashes them. A field added since must declare opt(neutral=...); one that does not fails here.
IDENTITY_BASE = (
    "iters res labels fov_deg layout backend sh_degree sh_increase_every coarse_until strategy densify_from "
    "densify_until grad_threshold w_l1 w_ssim w_depth lr_means lr_means_final lr_quats lr_scales lr_opacities "
    "lr_sh0 lr_shN checkpoint_every heldout history_every eval_at sky init_opacity disocclusion_fill_deg "
    "disocclusion_fill_visits disocclusion_opacity init_pixels_per_point seed"
).split()


def test_every_train_field_added_after_the_first_tables_declares_its_neutral_value():
    without = [f.name for f in dataclasses.fields(TrainConfig) if "neutral" not in f.metadata]
    assert without == IDENTITY_BASE, (
        "a TrainConfig field added since the committed tables must declare opt(neutral=<the value that behaves as "
        f"before it existed>): {sorted(set(without) - set(IDENTITY_BASE))}"
    )
    for f in dataclasses.fields(TrainConfig):  # a neutral value must be a valid setting of the field
        if "neutral" in f.metadata:
            TrainConfig(**{f.name: f.metadata["neutral"]})


def test_every_fusion_option_declares_its_neutral_value():
    assert all("neutral" in f.metadata for f in dataclasses.fields(FusionOptions))
    off = FusionOptions(**{f.name: f.metadata["neutral"] for f in dataclasses.fields(FusionOptions)})
    assert off.config().edge_jump is None and off.config().edge_reach == 0


@dataclasses.dataclass(frozen=True)
class _Config:
    a: int = opt(1, "always in")
    b: float = opt(0.0, "added later, off by default", neutral=0.0)
    c: int = opt(5, "added later, on by default", neutral=0)
    d: bool = opt(False, "a switch added later", neutral=False)


def test_identity_leaves_out_exactly_the_fields_at_their_neutral_value():
    assert identity(_Config()) == {"a": 1, "c": 5}
    assert identity(_Config(c=0)) == {"a": 1}
    assert identity(_Config(b=0.5, d=True)) == {"a": 1, "b": 0.5, "c": 5, "d": True}
    assert identity(_Config(a=0, c=0)) == {"a": 0}  # a field without a neutral value is in at any value


def test_a_switch_is_not_its_integer():
    @dataclasses.dataclass(frozen=True)
    class Flags:
        n: int = opt(0, "a count", neutral=False)

    assert identity(Flags(n=0)) == {"n": 0}  # 0 is not False: a declared False neutral does not swallow a 0


def test_a_new_option_at_its_neutral_value_leaves_every_run_identity_as_it_was(monkeypatch):
    base = Row("bedroom", 512, "fibonacci", "sim:relative", train={"iters": 2000, "flatten_every": 0})
    before = base.run_id()
    # a field appended to TrainConfig with its neutral value as the default: the same runs, the same identities
    extended = dataclasses.make_dataclass(
        "TrainConfig",
        [("w_new", float, opt(0.0, "a new regulariser", check=C.LOSS_WEIGHT, neutral=0.0))],
        bases=(TrainConfig,),
        frozen=True,
    )
    monkeypatch.setattr("panorecon.splat.trainer.TrainConfig", extended)
    assert base.run_id() == before
    assert dataclasses.replace(base, train={**base.train, "w_new": 0.1}).run_id() != before


def test_a_moved_default_is_another_run_and_pinning_it_gives_the_old_one():
    today = Row("bedroom", 512, "fibonacci", "sim:relative", train={"iters": 2000})
    pinned = dataclasses.replace(today, train={"iters": 2000, "flatten_every": 0})
    assert today.run_id() != pinned.run_id()
    assert "flatten_every" not in pinned._train_params()["config"]
    assert today._train_params()["config"]["flatten_every"] == 100


def test_fusion_settings_enter_the_points_identity_only_away_from_their_neutral_value():
    row = Row("bedroom", 512, "fibonacci", "sim:relative")
    assert row._points_params()["fusion"] == {
        "edge_jump": pytest.approx(0.4054651081081644),
        "edge_reach": 3,
        "affine_gauge": "reference",
    }
    off = dataclasses.replace(row, fusion={"edge_jump": 0.0, "edge_reach": 0, "affine_gauge": "mean-shift"})
    assert "fusion" not in off._points_params()
    assert len({row.points_key(), off.points_key(), row.run_id(), off.run_id()}) == 4
    assert off.fusion_options().config().edge_jump is None  # 0: off, as the fusion's None


def test_fusion_options_are_checked_by_their_declaration():
    with pytest.raises(ValueError, match="edge_reach"):
        FusionOptions(edge_reach=-1)
    with pytest.raises(ValueError, match="edge_jump"):
        FusionOptions(edge_jump=float("nan"))
    with pytest.raises(ValueError, match="affine_gauge"):
        FusionOptions(affine_gauge="median")
