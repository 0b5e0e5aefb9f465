"""The bpy-free scene model: derived values, Blender camera conventions, validation."""
import numpy as np
import pytest

from hybrid_shadow_addon.core.errors import SceneError
from hybrid_shadow_addon.core.scene import Camera, Instances, Light, Model, Scene


def cube_model(name="cube", size=2.0):
    v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float32) * size / 2
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = [(a, b, c) for a, b, c, d in faces] + [(a, c, d) for a, b, c, d in faces]
    return Model(name, v, np.array(tris))


def translate(x, y, z, s=1.0):
    m = np.eye(4)
    m[:3, :3] *= s
    m[:3, 3] = (x, y, z)
    return m


def test_model_bounds_and_sphere_hold_every_vertex():
    rng = np.random.default_rng(1)
    m = Model("rand", rng.normal(size=(500, 3)) * [3, 1, 0.2] + [10, -4, 2], rng.integers(0, 500, (100, 3)))
    assert m.vertices.dtype == np.float32 and m.triangles.dtype == np.uint32
    assert np.all(m.vertices >= m.bounds_min) and np.all(m.vertices <= m.bounds_max)
    d = np.linalg.norm(m.vertices.astype(np.float64) - m.sphere_center, axis=1)
    assert d.max() <= m.sphere_radius


def test_instances_inverse_and_world_spheres():
    cube = cube_model()
    rot = np.array([[0, -1, 0, 0], [1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], float)
    mats = np.stack([translate(5, 0, 1), rot @ np.diag([1, 3, 0.5, 1.0]), translate(0, 0, 0, -2)])
    inst = Instances(names=["a", "b", "c"], model_ids=[0, 0, 0], matrices=mats)
    np.testing.assert_allclose(inst.inverse @ inst.matrices, np.tile(np.eye(4), (3, 1, 1)), atol=1e-12)
    np.testing.assert_allclose(inst.max_scale(), [1, 3, 2])
    scene = Scene(models=[cube], instances=inst, camera=Camera())
    centers, radii = scene.instance_spheres()
    np.testing.assert_allclose(centers[0], [5, 0, 1])
    np.testing.assert_allclose(radii, np.sqrt(3) * np.array([1, 3, 2]), rtol=1e-6)
    lo, hi = scene.world_bounds()
    np.testing.assert_allclose(lo, [-3, -2, -2])
    np.testing.assert_allclose(hi, [6, 2, 2])
    assert scene.triangle_count == 36 and scene.unique_triangle_count == 12


def test_validation_names_the_bad_object():
    cube = cube_model()
    bad = translate(0, 0, 0)
    bad[0, 3] = np.nan
    scene = Scene(models=[cube], instances=Instances(names=["ok", "Broken.001"], model_ids=[0, 0],
                                                     matrices=[translate(0, 0, 0), bad]), camera=Camera())
    with pytest.raises(SceneError, match="Broken.001"):
        scene.validate()
    scene.instances.set_matrices([1], translate(0, 0, 0, 0.0))
    with pytest.raises(SceneError, match="'Broken.001' has a zero scale"):
        scene.validate()
    scene.instances.set_matrices([1], translate(1, 2, 3))
    scene.validate()
    scene.lights.append(Light("Lamp", "POINT", power=np.inf))
    with pytest.raises(SceneError, match="light 'Lamp'"):
        scene.validate()
    scene.lights[0].power = 10.0
    scene.camera = None
    with pytest.raises(SceneError, match="no camera"):
        scene.validate()
    scene.validate(require_camera=False)
    with pytest.raises(SceneError, match="NaN or infinite vertex"):
        Scene(models=[Model("nanmesh", [[0, 0, np.inf]], [[0, 0, 0]])]).validate(require_camera=False)


def test_light_direction_is_local_minus_z():
    m = np.eye(4)
    m[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # 90 degrees about X
    light = Light("Sun", "sun", matrix=m)
    assert light.type == "SUN"
    np.testing.assert_allclose(light.direction, [0, 1, 0], atol=1e-12)


@pytest.mark.parametrize("fit,w,h", [("AUTO", 640, 360), ("AUTO", 300, 600), ("HORIZONTAL", 300, 600),
                                     ("VERTICAL", 640, 360)])
def test_camera_projection_matches_pixel_rays(fit, w, h):
    """Projecting a point along the centre ray of pixel (i, j) lands on that pixel's centre."""
    cam_m = translate(1, -8, 3)
    cam_m[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]  # looking along +Y
    for ctype in ("PERSP", "ORTHO"):
        cam = Camera(matrix=cam_m, type=ctype, sensor_fit=fit, shift_x=0.1, shift_y=-0.05, lens=35)
        o, d = cam.pixel_rays(w, h)
        P = cam.projection_matrix(w, h) @ cam.view_matrix()
        for (i, j) in [(0, 0), (h - 1, w - 1), (h // 3, w // 2)]:
            p = o[i, j] + d[i, j] * 7.0
            clip = P @ np.append(p, 1)
            ndc = clip[:3] / clip[3]
            px = (ndc[0] + 1) / 2 * w
            py = (1 - (ndc[1] + 1) / 2) * h  # row 0 = top
            assert abs(px - (j + 0.5)) < 1e-6 and abs(py - (i + 0.5)) < 1e-6
            assert -1 < ndc[2] < 1


def test_camera_sensor_fit_field_of_view():
    cam = Camera(lens=50, sensor_width=36, sensor_height=24, sensor_fit="AUTO")
    left, right, bottom, top = cam.viewplane(640, 360)
    # horizontal fit: the view plane's width at clip_start equals sensor_width * clip_start / lens
    assert np.isclose(right - left, 36 * cam.clip_start / 50)
    cam.sensor_fit = "VERTICAL"
    left, right, bottom, top = cam.viewplane(640, 360)
    assert np.isclose(top - bottom, 24 * cam.clip_start / 50)
