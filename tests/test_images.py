"""`util.image.to_uint8` against its closed form, and `run.outputs.grid_cells` against a grid
laid out by hand."""

import numpy as np

from gae_jax.run import outputs
from gae_jax.util.image import to_uint8


def test_to_uint8_clips_and_rounds_to_the_nearest_level():
    x = np.array([-0.5, 0.0, 0.4 / 255, 0.6 / 255, 127.49 / 255, 127.51 / 255, 1.0, 2.0])
    np.testing.assert_array_equal(to_uint8(x), [0, 0, 0, 1, 127, 128, 255, 255])
    levels = np.arange(256) / 255.0
    np.testing.assert_array_equal(to_uint8(levels.astype(np.float32)), np.arange(256))
    np.testing.assert_array_equal(to_uint8(np.arange(3)), [0, 255, 255])  # integers: as floats
    assert to_uint8(np.zeros((2, 3, 3), np.float32)).dtype == np.uint8


def test_grid_cells_are_the_cells_a_grid_was_laid_out_from():
    rows, columns, size = 3, len(outputs.GRID_COLUMNS) + 1, 16
    rng = np.random.default_rng(0)
    cells = rng.integers(0, 256, (rows, columns, size, size, 3), dtype=np.uint8)
    body = np.concatenate([np.concatenate(list(r), axis=1) for r in cells], axis=0)
    title = outputs.label(body.shape[1], "title", outputs.GRID_TEXT)
    header = outputs.label(body.shape[1], "header", outputs.GRID_TEXT)
    grid = np.concatenate([title, header, body], axis=0)
    np.testing.assert_array_equal(outputs.grid_cells(grid), cells)
