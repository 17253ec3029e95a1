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
