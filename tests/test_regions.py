"""A region's outline on a mesh (`regions.rim_faces`, the colour-ceiling study's rim), against a
grid counted by hand."""

import types

import numpy as np

from gae_jax.model import head, regions


def grid_scene(n: int, region_of_cell):
    """An n x n grid of squares, two triangles each; face region from its cell (i, j)."""
    vid = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    faces, regions = [], []
    for i in range(n):
        for j in range(n):
            a, b, c, d = vid[i, j], vid[i, j + 1], vid[i + 1, j], vid[i + 1, j + 1]
            faces += [(a, b, d), (a, d, c)]
            regions += [region_of_cell(i, j)] * 2
    return types.SimpleNamespace(model=types.SimpleNamespace(faces=np.asarray(faces)),
                                 face_regions=np.asarray(regions))


def test_the_rim_is_the_faces_on_the_regions_outline():
    lips, skin = head.REGION_ID["lips"], head.REGION_ID["skin"]
    # a 4 x 4 block of lips cells inside a 6 x 6 grid of skin
    scene = grid_scene(6, lambda i, j: lips if 1 <= i <= 4 and 1 <= j <= 4 else skin)
    rim = regions.rim_faces(scene.model.faces, scene.face_regions, "lips")
    cells = rim.reshape(6, 6, 2)
    assert not rim[scene.face_regions == skin].any()
    # the 2 x 2 interior cells have no open edge; of an outline cell, the triangle(s) touching
    # the outline: (a, b, d) holds the top and right edges, (a, d, c) the left and bottom ones
    assert not cells[2:4, 2:4].any()
    assert cells[1, 2:4, 0].all() and not cells[1, 2:4, 1].any()  # top row: top edge
    assert cells[4, 2:4, 1].all() and not cells[4, 2:4, 0].any()  # bottom row: bottom edge
    assert cells[2:4, 1, 1].all() and cells[2:4, 4, 0].all()  # left and right columns
    # corners: top-left and bottom-right need both triangles, the other two only one
    assert cells[1, 1].all() and cells[4, 4].all()
    assert cells[1, 4].tolist() == [True, False] and cells[4, 1].tolist() == [False, True]
    assert int(rim.sum()) == 4 * 2 + 6  # one triangle per side cell, six in the corners
