"""Light objects: every type with its colour, power, shape and shadow switch."""
import bpy
import numpy as np
import pytest

from hybrid_shadow_addon.core.errors import SceneError
from tests.helpers.export_scenes import add_object, empty_scene, export_scene

pytestmark = [pytest.mark.blender]


@pytest.fixture
def scene():
    """An empty scene with a camera."""
    return empty_scene()


# --------------------------------------------------------------------------------------------
# lights
# --------------------------------------------------------------------------------------------
def test_lights_of_every_type(scene):
    specs = {
        "Sun": ("SUN", dict(angle=0.1)),
        "Point": ("POINT", dict(shadow_soft_size=0.3)),
        "Spot": ("SPOT", dict(spot_size=1.0, spot_blend=0.4, shadow_soft_size=0.2)),
        "Area": ("AREA", dict(shape="RECTANGLE", size=2.0, size_y=0.5)),
        "Disk": ("AREA", dict(shape="DISK", size=1.5)),
    }
    for i, (name, (kind, props)) in enumerate(specs.items()):
        light = bpy.data.lights.new(name, kind)
        light.energy, light.color = 10.0 * (i + 1), (1, 0.5, 0.25)
        for k, v in props.items():
            setattr(light, k, v)
        ob = add_object(name, light, location=(i, 2 * i, 3 * i))
        ob.rotation_euler = (0.3 * i, 0.1, 0.2)
    bpy.data.lights["Point"].use_shadow = False
    s = export_scene()
    got = {light.name: light for light in s.lights}
    assert s.lights_by_type() == {"SUN": 1, "POINT": 1, "SPOT": 1, "AREA": 2}
    for name, (kind, _props) in specs.items():
        light, ob = got[name], bpy.data.objects[name]
        assert light.type == kind and light.power == pytest.approx(ob.data.energy)
        np.testing.assert_allclose(light.matrix, np.array(ob.matrix_world), atol=1e-6)
        np.testing.assert_allclose(light.color, (1, 0.5, 0.25))
    assert got["Sun"].angle == pytest.approx(0.1)
    assert not got["Point"].use_shadow and got["Spot"].use_shadow
    assert got["Point"].radius == pytest.approx(0.3)
    assert (got["Spot"].spot_size, got["Spot"].spot_blend, got["Spot"].radius) == pytest.approx((1.0, 0.4, 0.2))
    assert (got["Area"].size, got["Area"].size_y, got["Area"].area_shape) == (2.0, 0.5, "RECTANGLE")
    assert (got["Disk"].size, got["Disk"].size_y) == (1.5, 1.5)


def test_nan_light_transform_is_rejected(scene):
    add_object("Lamp", bpy.data.lights.new("Lamp", "POINT")).location = (0, float("nan"), 0)
    with pytest.raises(SceneError, match="light 'Lamp'"):
        export_scene()
