"""The acceleration-structure interface: the registry, the one default, both structures' oracles
agreeing on a random scene, and the occupancy the Grid Occupancy debug view shows."""
import re
from pathlib import Path

import numpy as np
import pytest

from hybrid_shadow_addon.core.bake import BakeConfig, bake_scene
from hybrid_shadow_addon.core.bake.structures import (
    DEFAULT_STRUCTURE,
    STRUCTURES,
    AccelerationStructure,
    HierarchicalGrid,
    TwoLevelBVH,
    structure_class,
)
from hybrid_shadow_addon.core.oracle.tracer import trace_brute, trace_structured
from hybrid_shadow_addon.core.scene import Instances, Model, Scene
from hybrid_shadow_addon.core.settings import Settings

REPO = Path(__file__).resolve().parents[1]


def soup_model(rng, n_tri, name):
    """Random overlapping triangles in a unit box."""
    c = rng.uniform(-1, 1, (n_tri, 1, 3))
    v = (c + rng.normal(scale=0.3, size=(n_tri, 3, 3))).reshape(-1, 3)
    return Model(name, v, np.arange(3 * n_tri).reshape(-1, 3))


def random_scene(rng, n=120, area=20.0):
    """Meshes and analytic spheres, rotated, scaled and spread over a square."""
    models = [soup_model(rng, k, f"soup{k}") for k in (1, 10, 80)]
    M = np.tile(np.eye(4), (n, 1, 1))
    a = rng.uniform(0, 2 * np.pi, n)
    s = rng.uniform(0.4, 2.0, n)
    M[:, 0, 0], M[:, 0, 1], M[:, 1, 0], M[:, 1, 1] = s * np.cos(a), -s * np.sin(a), s * np.sin(a), s * np.cos(a)
    M[:, 2, 2] = s
    M[:, :2, 3] = rng.uniform(-area, area, (n, 2))
    M[:, 2, 3] = rng.uniform(0, 3, n)
    inst = Instances(names=[f"o{i}" for i in range(n)], model_ids=rng.integers(0, len(models), n), matrices=M,
                     sphere=rng.random(n) < 0.25, casts_shadow=rng.random(n) < 0.9)
    return Scene(models=models, instances=inst)


def random_rays(rng, scene, n):
    """Half aimed at instance centres, half random; finite and infinite lengths."""
    c = scene.instances.matrices[:, :3, 3]
    lo, hi = scene.world_bounds()
    o = rng.uniform(lo - 3, hi + 3, (n, 3))
    d = rng.normal(size=(n, 3))
    k = n // 2
    d[:k] = c[rng.integers(0, len(c), k)] + rng.normal(scale=0.5, size=(k, 3)) - o[:k]
    return o, d, rng.choice([np.inf, 1.0, 20.0], n)


def test_both_structures_registered():
    assert set(STRUCTURES) == {"grid", "bvh"}
    assert STRUCTURES["grid"] is HierarchicalGrid and STRUCTURES["bvh"] is TwoLevelBVH
    shared = (REPO / "shaders" / "common" / "scene_data.glsl").read_text()
    for name, cls in STRUCTURES.items():
        assert issubclass(cls, AccelerationStructure) and cls.name == name
        assert structure_class(name) is cls
        assert (REPO / "shaders" / cls.glsl_include).is_file()
        # scene_data.glsl includes the structure's file under the structure's define
        define = f"HS_STRUCTURE_{name.upper()}"
        assert re.search(rf'defined\({define}\)\s*\n#include "{re.escape(cls.glsl_include)}"', shared)
    with pytest.raises(ValueError):
        structure_class("octree")
    with pytest.raises(ValueError):
        BakeConfig(structure="octree")


def test_default_defined_once():
    assert DEFAULT_STRUCTURE in STRUCTURES
    assert Settings().structure == DEFAULT_STRUCTURE
    assert BakeConfig().structure == DEFAULT_STRUCTURE
    assert bake_scene(Scene()).structure == DEFAULT_STRUCTURE
    src = REPO / "hybrid_shadow_addon"
    hits = [p for p in src.rglob("*.py") if re.search(r"^DEFAULT_STRUCTURE\s*=", p.read_text(), re.M)]
    assert [p.relative_to(src).as_posix() for p in hits] == ["core/bake/structures/__init__.py"]
    # Blender's property and the command line take the default from the setting's declaration
    from hybrid_shadow_addon.__main__ import build_parser
    from hybrid_shadow_addon.core.settings import FIELDS, from_arguments

    assert FIELDS["structure"].default == DEFAULT_STRUCTURE
    assert "DEFAULT_STRUCTURE" not in (src / "blender" / "properties.py").read_text()
    args = build_parser().parse_args(["render", "forest", "--output", "x.png"])
    assert args.structure is None and from_arguments(args, args.setting_names).structure == DEFAULT_STRUCTURE


@pytest.mark.parametrize("seed", range(2))
def test_both_oracles_same_masks(seed):
    rng = np.random.default_rng(seed)
    scene = random_scene(rng)
    o, d, t = random_rays(rng, scene, 3000)
    brute = trace_brute(scene, o, d, t)
    for name in STRUCTURES:
        baked = bake_scene(scene, BakeConfig(structure=name))
        assert isinstance(baked.accel, STRUCTURES[name]) and baked.structure == name
        assert f"HS_STRUCTURE_{name.upper()}" in baked.defines
        occ = trace_structured(baked, o, d, t)
        assert (occ == brute).all(), f"{name}: {(occ != brute).sum()} rays differ from brute force"
    assert 0.05 < brute.mean() < 0.95


@pytest.mark.parametrize("structure", sorted(STRUCTURES))
def test_model_edit_matches_fresh_bake(structure):
    """The shared model rebuild: an edited and an appended model trace like a fresh bake."""
    rng = np.random.default_rng(5)
    scene = random_scene(rng, n=60)
    baked = bake_scene(scene, BakeConfig(structure=structure))
    scene.models[1] = soup_model(rng, 300, "soup300")  # larger: moves to the tail
    baked.update_model(scene, 1)
    scene.models.append(soup_model(rng, 7, "new"))
    ids = scene.instances.model_ids.copy()
    ids[:5] = len(scene.models) - 1
    scene.instances.model_ids[:] = ids
    baked.update_model(scene, len(scene.models) - 1)
    o, d, t = random_rays(rng, scene, 2000)
    assert (trace_structured(baked, o, d, t) == trace_brute(scene, o, d, t)).all()
    assert baked.stats["models"] == len(scene.models)


@pytest.mark.parametrize("structure", sorted(STRUCTURES))
def test_occupancy_under_both_structures(structure):
    """The Grid Occupancy debug view shows something under either structure: positive over the
    casters, -1 where there is no geometry."""
    pytest.importorskip("bpy")
    from hybrid_shadow_addon.blender.viewport import grid_occupancy
    rng = np.random.default_rng(3)
    scene = random_scene(rng, n=80)
    baked = bake_scene(scene, BakeConfig(structure=structure))
    h, w = 8, 16
    pos = np.zeros((h, w, 4), np.float32)
    cast = np.nonzero(scene.instances.casts_shadow)[0]
    pts = scene.instance_spheres(cast[: h * w // 2])[0]  # the casters' bounding-sphere centres
    flat = pos.reshape(-1, 4)
    flat[: len(pts), :3] = pts
    flat[: len(pts), 3] = 1.0
    occ = grid_occupancy(baked, pos)
    assert occ.shape == (h, w)
    valid = pos[..., 3] > 0.5
    assert (occ[~valid] == -1).all()
    assert (occ[valid] >= 1).all()  # each point lies over its own caster
    far = baked.occupancy(np.array([[1e6, 1e6, 0.0]]))
    assert far.shape == (1,) and far[0] <= occ[valid].min()
