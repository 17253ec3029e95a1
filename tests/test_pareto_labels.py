"""benchmarks/pareto.py's chart labels: points close on both axes share one label, a line per
point from the highest down; points apart keep their own."""

from tests.helpers import load_script


def test_close_points_share_one_label_from_the_highest_down():
    pareto = load_script("benchmarks/pareto.py")
    xs = [0.0, 10.0, 10.5, 10.2, 0.0]
    ys = [0.0, 5.0, 5.2, 4.7, 10.0]
    labels = pareto.label_groups(xs, ys, ["low", "b", "a", "c", "high"])
    assert labels == [(0.0, 0.0, "low"), (10.5, 5.2, "a\nb\nc"), (0.0, 10.0, "high")]
