"""Scenes of paper 000 III-B: named functions of a difficulty and a seed, centred on the start."""

import numpy as np
import pytest

from qz_drake.capability.scenes import (IRREGULAR_KINDS, REGULAR_KINDS, SCENE_FUNCTIONS, SCENE_HALF_SIZE,
                                        make_scene, scene_for, scene_recipe)
from qz_drake.errors import QzError


@pytest.mark.parametrize("kind", sorted(SCENE_FUNCTIONS))
def test_every_kind_is_a_centred_finite_map_that_grows_harder(kind):
    easy, hard = make_scene(kind, 0.0, 7), make_scene(kind, 1.0, 7)
    for scene in (easy, hard):
        xmin, xmax, ymin, ymax = scene.heightmap.bounds
        assert xmin < -SCENE_HALF_SIZE + 0.1 and xmax > SCENE_HALF_SIZE - 0.1
        assert ymin < -SCENE_HALF_SIZE + 0.1 and ymax > SCENE_HALF_SIZE - 0.1
        assert np.all(np.isfinite(scene.heightmap.heights))
    if kind != "flat":
        spread = [np.mean(np.abs(s.heightmap.heights)) for s in (easy, hard)]
        assert spread[1] > spread[0]


def test_scenes_are_reproducible_and_split_70_30():
    a, b = scene_for(3, 11), scene_for(3, 11)
    assert a.kind == b.kind and np.array_equal(a.heightmap.heights, b.heightmap.heights)
    kinds = [scene_recipe(0, i)[0] for i in range(1000)]
    regular = sum(k in REGULAR_KINDS for k in kinds)
    assert 650 <= regular <= 750
    assert set(kinds) == set(REGULAR_KINDS) | set(IRREGULAR_KINDS)


def test_bad_scene_requests_name_the_field():
    with pytest.raises(QzError, match="scene.kind"):
        make_scene("lava", 0.5, 0)
    with pytest.raises(QzError, match="scene.difficulty"):
        make_scene("stairs", 1.5, 0)
