"""Typed configuration: presets, overrides, CLI flags, documentation of every setting."""

import argparse
import dataclasses

import pytest

from lift3d.errors import InputError
from lift3d.train.config import (
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
    assert fast.field.head_hidden_dim <= bal.field.head_hidden_dim <= qual.field.head_hidden_dim
    assert qual.field.head_hidden_dim == 256  # the paper's decoder width


def test_overrides_win_and_coerce_types():
    cfg = load_config("fast", "outdoor", {"optim": {"steps": "12"}, "field": {"understanding_resolutions": [8, 16]},
                                          "losses": {"use_confidence": "false"}})
    assert cfg.optim.steps == 12 and cfg.field.understanding_resolutions == (8, 16)
    assert cfg.losses.use_confidence is False and cfg.field.contraction == "linf"


def test_unknown_setting_is_a_clear_error():
    with pytest.raises(InputError, match="unknown setting 'stepz'"):
        load_config("fast", overrides={"optim": {"stepz": 3}})
    with pytest.raises(InputError, match="unknown preset"):
        load_config("turbo")
    with pytest.raises(InputError, match="expected int"):
        load_config("fast", overrides={"optim": {"steps": "many"}})


def test_round_trip_through_dict():
    cfg = load_config("quality", "outdoor", {"trainer": {"seed": 7}})
    assert config_from_dict(cfg.to_dict()) == cfg


def test_every_setting_is_documented_and_is_a_flag():
    parser = argparse.ArgumentParser()
    add_config_flags(parser)
    defaults = Config()
    for section in SECTIONS:
        sub = getattr(defaults, section)
        docs = field_docs(type(sub))
        for f in dataclasses.fields(sub):
            assert docs.get(f.name), f"{section}.{f.name} has no documentation"
    args = parser.parse_args(["--optim.steps", "5", "--field.understanding-resolutions", "16", "32",
                              "--losses.feature", "0"])
    assert overrides_from_args(args) == {"optim": {"steps": "5"}, "field": {"understanding_resolutions": ["16", "32"]},
                                         "losses": {"feature": "0"}}
    cfg = load_config("fast", overrides=overrides_from_args(args))
    assert cfg.optim.steps == 5 and cfg.field.understanding_resolutions == (16, 32) and cfg.losses.feature == 0.0
