"""The exact float64 numpy ray caster the GPU tests compare with (``helpers/rays.py``)."""
import numpy as np

from tests.helpers.rays import ray_cast
from tests.helpers.scenes import basic_scene


def test_ray_cast_helper_hits_the_cube_top():
    scene = basic_scene()
    t, i, f = ray_cast(scene, np.array([[0.0, 0.0, 10.0]]), np.array([[0.0, 0.0, -1.0]]))
    assert i[0] == 1 and abs(t[0] - 8.0) < 1e-12
