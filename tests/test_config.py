"""Typed configuration: presets, overrides, CLI flags, documentation of every setting, the old layout."""

import argparse
import dataclasses

import pytest

from lift3d.errors import InputError
from lift3d.field.registry import FIELD_KINDS, FieldConfig, build_field
from lift3d.model.config import (
    PRESETS,
    SCENE_KINDS,
    SECTIONS,
    Config,
    add_config_flags,
    config_from_dict,
    field_docs,
    load_config,
    overrides_from_args,
)


@pytest.mark.parametrize("preset", ["fast", "balanced", "quality"])
def test_presets_load_and_are_ordered_by_cost(preset):
    cfg = load_config(preset, "indoor")
    assert cfg.preset == preset and cfg.field.contraction == "none"


def test_presets_trade_speed_for_accuracy():
    fast, bal, qual = (load_config(p) for p in ("fast", "balanced", "quality"))
    assert fast.optim.steps < bal.optim.steps < qual.optim.steps
    assert fast.field.grid.head_hidden_dim <= bal.field.grid.head_hidden_dim <= qual.field.grid.head_hidden_dim
    assert qual.field.grid.head_hidden_dim == 256  # the paper's decoder width


def test_overrides_win_and_coerce_types():
    cfg = load_config("fast", "outdoor", {"optim": {"steps": "12"},
                                          "field": {"grid": {"understanding_resolutions": [8, 16]}},
                                          "losses": {"use_confidence": "false"}})
    assert cfg.optim.steps == 12 and cfg.field.grid.understanding_resolutions == (8, 16)
    assert cfg.losses.use_confidence is False and cfg.field.contraction == "linf"


def test_unknown_setting_is_a_clear_error():
    with pytest.raises(InputError, match="unknown setting 'stepz'"):
        load_config("fast", overrides={"optim": {"stepz": 3}})
    with pytest.raises(InputError, match="unknown preset"):
        load_config("turbo")
    with pytest.raises(InputError, match="expected int"):
        load_config("fast", overrides={"optim": {"steps": "many"}})
    with pytest.raises(InputError, match="unknown field kind 'hash'.*grid, mlp"):
        load_config("fast", overrides={"field": {"kind": "hash"}})
    with pytest.raises(InputError, match=r"sampling.render_label_coverage: must be in \[0, 1\], got 1.5"):
        load_config("fast", overrides={"sampling": {"render_label_coverage": 1.5}})
    with pytest.raises(InputError, match=r"sampling.render_color_coverage: must be in \[0, 1\], got -0.1"):
        load_config("fast", overrides={"sampling": {"render_color_coverage": -0.1}})
    with pytest.raises(InputError, match=r"field.scene_box_pad: must be in \[0, 1\), got -0.01"):
        load_config("fast", overrides={"field": {"scene_box_pad": -0.01}})
    with pytest.raises(InputError, match="field:grid.*unknown setting 'levelz'"):
        load_config("fast", overrides={"field": {"grid": {"levelz": 2}}})


def test_round_trip_through_dict():
    cfg = load_config("quality", "outdoor", {"trainer": {"seed": 7}, "field": {"mlp": {"width": 32}}})
    assert config_from_dict(cfg.to_dict()) == cfg


def test_old_flat_field_layout_still_loads():
    """config.yml / checkpoints written before the per-kind sections keep loading (the keys move)."""
    old = {"preset": "fast", "field": {"kind": "grid", "grid_levels": 2, "grid_min_resolution": 8,
                                       "grid_max_resolution": 48, "grid_resolution_cap": 96, "grid_channels": 2,
                                       "coarse_to_fine": 0.25, "head_hidden_dim": 32, "understanding_resolutions": [16],
                                       "mlp_width": 64, "mlp_depth": 3, "mlp_frequencies": 6,
                                       "num_semantic_classes": 5, "contraction": "none", "sh_degree": 2}}
    cfg = config_from_dict(old)
    g, m = cfg.field.grid, cfg.field.mlp
    assert (g.levels, g.min_resolution, g.max_resolution, g.resolution_cap, g.channels) == (2, 8, 48, 96, 2)
    assert (g.coarse_to_fine, g.head_hidden_dim, g.understanding_resolutions) == (0.25, 32, (16,))
    assert (m.width, m.depth, m.frequencies) == (64, 3, 6)
    assert (cfg.field.num_semantic_classes, cfg.field.contraction, cfg.field.sh_degree) == (5, "none", 2)
    assert config_from_dict(cfg.to_dict()) == cfg


def test_old_flat_field_flags_still_apply():
    """Scripts that pass the old flat flags (--field.grid-resolution-cap 16) keep working."""
    cfg = load_config("fast", overrides={"field": {"grid_resolution_cap": 16, "mlp_width": 32}})
    assert (cfg.field.grid.resolution_cap, cfg.field.mlp.width) == (16, 32)


def _sections(obj, path):
    """(dotted path, dataclass) of a config section and every section nested in it."""
    yield path, obj
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if dataclasses.is_dataclass(value):
            yield from _sections(value, f"{path}.{f.name}")


def test_every_setting_is_documented_and_is_a_flag():
    parser = argparse.ArgumentParser()
    add_config_flags(parser)
    flags = {a.dest for a in parser._actions}
    defaults = Config()
    for section in SECTIONS:
        for path, sub in _sections(getattr(defaults, section), section):
            docs = field_docs(type(sub))
            assert (type(sub).__doc__ or "").strip(), f"{path} has no class documentation"
            for f in dataclasses.fields(sub):
                if dataclasses.is_dataclass(getattr(sub, f.name)):
                    continue
                assert docs.get(f.name), f"{path}.{f.name} has no documentation"
                assert f"cfg:{path}.{f.name}" in flags, f"{path}.{f.name} has no flag"
    args = parser.parse_args(["--optim.steps", "5", "--field.grid.understanding-resolutions", "16", "32",
                              "--losses.feature", "0", "--field.mlp.width", "64", "--field.kind", "mlp"])
    assert overrides_from_args(args) == {"optim": {"steps": "5"}, "losses": {"feature": "0"},
                                         "field": {"grid": {"understanding_resolutions": ["16", "32"]},
                                                   "mlp": {"width": "64"}, "kind": "mlp"}}
    cfg = load_config("fast", overrides=overrides_from_args(args))
    assert cfg.optim.steps == 5 and cfg.field.grid.understanding_resolutions == (16, 32) and cfg.losses.feature == 0.0
    assert cfg.field.kind == "mlp" and cfg.field.mlp.width == 64 and cfg.field.kind_config is cfg.field.mlp


def _flag_help() -> dict[str, str]:
    parser = argparse.ArgumentParser()
    add_config_flags(parser)
    return {a.dest[4:]: " ".join(a.help.split()) for a in parser._actions if a.dest.startswith("cfg:")}


def test_help_of_a_preset_setting_shows_the_preset_value():
    """The presets all set losses.image_depth to 0.1; its dataclass default 0.0 alone would mislead."""
    helps = _flag_help()
    assert load_config("fast").losses.image_depth == 0.1 and Config().losses.image_depth == 0.0
    assert helps["losses.image_depth"].endswith("(default: 0.1 in every preset, else 0.0)")
    assert helps["optim.steps"].endswith("(default: 1500 in fast, 5000 in balanced, 10000 in quality, else 3000)")
    assert helps["sampling.near_plane"].endswith("(default: 0.02 for bounded, 0.05 for unbounded scenes)")
    assert helps["trainer.seed"].endswith("(default: 0)")


def test_help_names_every_value_a_run_can_start_from():
    """Whatever preset and scene kind a run gets, each setting's help names the value it starts from."""
    helps = _flag_help()
    for preset in PRESETS:
        for kind in SCENE_KINDS:
            cfg = load_config(preset, kind)
            for section in SECTIONS:
                for path, sub in _sections(getattr(cfg, section), section):
                    for f in dataclasses.fields(sub):
                        value = getattr(sub, f.name)
                        if not dataclasses.is_dataclass(value):
                            default = helps[f"{path}.{f.name}"].rsplit("(default: ", 1)[1]
                            assert repr(value) in default, (preset, kind, f"{path}.{f.name}", default)


@pytest.mark.parametrize("kind", sorted(FIELD_KINDS))
def test_every_field_kind_is_registered_with_its_section(kind):
    entry = FIELD_KINDS[kind]
    cfg = FieldConfig(kind=kind, num_semantic_classes=3, num_instance_channels=2, contraction="none")
    assert isinstance(getattr(cfg, kind), entry.config)
    cfg.grid.max_resolution, cfg.grid.min_resolution, cfg.grid.head_hidden_dim = 8, 8, 8
    cfg.mlp.width, cfg.mlp.depth = 8, 2
    field = build_field(cfg)
    assert type(field) is entry.field and field.has_instances
    assert cfg.kind_config.derive_sizes(lambda cap, minimum: (minimum, "test")) == {}  # nothing left at 0
