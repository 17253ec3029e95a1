"""benchmarks/region_ceiling.py's `--variant` settings: parsed strictly, named in the record,
and named back in the report's command."""

import argparse
import os

import pytest

from tests.helpers import load_script

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture
def region_ceiling(monkeypatch):
    monkeypatch.syspath_prepend(os.path.join(ROOT, "benchmarks"))  # its sibling `instructions`
    return load_script("benchmarks/region_ceiling.py")


def test_settings_are_reconstruction_fields_with_json_values(region_ceiling):
    assert region_ceiling.parse_settings("per_face=2,label_samples=false") == (
        ("per_face", 2), ("label_samples", False))
    for bad in ("colour=1", "per_face", "per_face=two", "iterations=5"):
        with pytest.raises(argparse.ArgumentTypeError, match="per_face|colour|iterations"):
            region_ceiling.parse_settings(bad)


def test_the_report_names_the_command_that_makes_each_variant(region_ceiling):
    settings = (("per_face", 2), ("densify_every", 100))
    name = region_ceiling.variant_name(0.1, False, 0.1, settings)
    assert name == "0.1 unseen 0.1 per_face=2 densify_every=100"
    regions = ("whole",) + region_ceiling.head.REGIONS
    record = dict(gaussians=7, reconstruction={r: 30.0 for r in regions}, ceilings={})
    report = region_ceiling.markdown({"0.1": record, name: record}, prompts=[])
    command = report.split("`")[1]
    assert command.count("--variant") == 1
    assert region_ceiling.parse_settings(command.split("--variant ")[1]) == settings
    assert "| Gaussians | 7 | 7 |" in report


def _record(whole, ceilings):
    regions = ("whole",) + ("skin",)
    return dict(gaussians=1, reconstruction={r: whole for r in regions}, ceilings=ceilings)


def test_a_variant_fitted_at_several_seeds_is_reported_as_its_mean(region_ceiling):
    assert region_ceiling.seed_of("0.1 unseen 0.1 per_face=2 seed=2") == (
        "0.1 unseen 0.1 per_face=2", 2)
    assert region_ceiling.seed_of("0.05") == ("0.05", 0)
    lips = "turn the lips blue"
    results = {
        "0.1 unseen 0.1": _record(35.0, {lips: dict(edited=28.0, worst_loss=0.1)}),
        "0.1 unseen 0.1 seed=1": _record(34.0, {lips: dict(edited=27.0, worst_loss=0.5)}),
        "0.1 unseen 0.1 seed=2": _record(34.6, {lips: dict(edited=26.0, worst_loss=0.9)}),
        "0.05": _record(33.0, {lips: dict(edited=20.0, worst_loss=0.0)}),  # one seed: no row
    }
    table = region_ceiling.seed_means(results, [lips])
    assert "0.1 unseen 0.1 (seeds 0, 1, 2)" in table and "0.05" not in table
    assert "| reconstruction, whole | 34.53 (34.00..35.00) |" in table
    assert "| clean ceilings (worst <= 0.3), per seed | 1 / 0 / 0 |" in table
    assert f"| ceiling: {lips} | 27.00 (26.00..28.00), worst 0.50 (0.10..0.90) |" in table
    assert region_ceiling.seed_means({"0.05": results["0.05"]}, [lips]) == ""


def test_the_command_names_the_seeds_it_fitted(region_ceiling):
    record = _record(30.0, {})
    default_seeds = {"0.1 unseen 0.1": record, "0.1 unseen 0.1 seed=1": record,
                     "0.1 unseen 0.1 per_face=2 seed=2": record}
    assert region_ceiling.command_flags(default_seeds) == (
        " --variant per_face=2,seed=2 --variant seed=1")
    weights_at_seeds = {"0.0": record, "0.05 seed=2": record, "0.1 centre seed=1": record}
    assert region_ceiling.command_flags(weights_at_seeds) == " --seeds 0 1 2"
