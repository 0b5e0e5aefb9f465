"""The scene's record textures as buffer textures (the default where the GL has them) and as 2D
array textures (the fallback): the same texels, so bit-identical masks, for both structures,
alpha-cut casters, soft shadows' packets and incremental updates; the fallback is taken when a
texture outgrows the buffer textures' limit, and asking for buffers where they cannot hold the
scene is one clear error."""
import numpy as np
import pytest

from hybrid_shadow_addon.core.errors import GPUError
from hybrid_shadow_addon.core.gpu import scene_textures as st_mod
from hybrid_shadow_addon.core.gpu.buffer_textures import BufferTexture, gl_functions, max_texels
from hybrid_shadow_addon.core.gpu.pipeline import Pipeline
from hybrid_shadow_addon.core.settings import Settings
from tests.helpers.scenes import blob_model

pytestmark = [pytest.mark.blender, pytest.mark.gpu]

W, H = 96, 72


def _masks(pipe, scene, settings):
    frame = pipe.render(scene, settings, W, H)
    return frame, {li: frame.mask_array(li) for li in frame.lights}


def _same(a: dict, b: dict):
    assert a.keys() == b.keys() and a
    for li in a:
        np.testing.assert_array_equal(a[li], b[li])


@pytest.fixture
def pair(gl_ctx):
    """Two pipelines on one context: record textures as buffers (default) and as 2D arrays."""
    buf, arr = Pipeline(gl_ctx), Pipeline(gl_ctx)
    arr.scene_textures.buffers = False
    yield buf, arr
    arr.release()
    buf.release()


def test_the_gl_here_has_buffer_textures(gl_ctx):
    assert gl_functions() is not None
    assert max_texels(gl_ctx) >= 65536  # GL 4.1's minimum


@pytest.mark.parametrize("name, structure, soft", [
    ("forest", "bvh", False), ("forest", "grid", False), ("alpha_cards", "bvh", False),
    ("alpha_cards", "grid", False), ("clusters", "bvh", True), ("alpha_cards", "bvh", True),
])
def test_buffers_and_arrays_give_the_same_masks(pair, loaded, name, structure, soft):
    buf, arr = pair
    scene = loaded(name)
    settings = Settings(mode="raytrace", hard=not soft, structure=structure)
    got = []
    for pipe in (buf, arr):
        pipe.set_scene(scene, structure)
        got.append(_masks(pipe, scene, settings)[1])
    assert buf.scene_textures.using_buffers and not arr.scene_textures.using_buffers
    assert all(isinstance(t, BufferTexture) == (n not in st_mod.ARRAY_ONLY)
               for n, t in buf.scene_textures.textures.items())
    _same(*got)


def test_the_define_follows_the_textures(pair, loaded):
    buf, arr = pair
    scene = loaded("cube_on_plane")
    for pipe, want in ((buf, True), (arr, False)):
        pipe.set_scene(scene)
        frame = pipe.render(scene, Settings(mode="raytrace", hard=True), W, H)
        assert ("HS_TEXEL_BUFFERS=1" in frame.stats["defines"]) is want


@pytest.mark.parametrize("structure", ["bvh", "grid"])
def test_updates_write_the_buffers_where_the_arrays_are_written(pair, loaded, gl_ctx, structure):
    """Moved instances (row ranges written in place) and an edited model that grows (textures
    re-created) give what a fresh bake gives, in both kinds of texture."""
    scene = loaded("forest")
    settings = Settings(mode="raytrace", hard=True, structure=structure)
    rng = np.random.default_rng(11)
    idx = rng.choice(len(scene.instances), 15, replace=False)
    before = scene.instances.matrices[idx].copy()
    m = before.copy()
    m[:, :3, 3] += rng.uniform(-12, 12, (15, 3)) * (1, 1, 0)
    model = int(scene.instances.model_ids[idx[0]])
    old_model = scene.models[model]
    try:
        for pipe in pair:
            pipe.set_scene(scene, structure)
        scene.instances.set_matrices(idx, m)
        scene.models[model] = blob_model(rng, 3000, "grown", size=3.0)
        results = []
        for pipe in pair:
            pipe.move_instances(scene, idx)
            pipe.update_model(scene, model)
            results.append(_masks(pipe, scene, settings)[1])
        fresh = Pipeline(gl_ctx)
        fresh.set_scene(scene, structure)
        _same(results[0], _masks(fresh, scene, settings)[1])
        fresh.release()
        _same(results[0], results[1])
    finally:
        scene.instances.set_matrices(idx, before)
        scene.models[model] = old_model


def test_arrays_where_a_texture_outgrows_the_limit(gl_ctx, loaded, monkeypatch):
    scene = loaded("forest")
    pipe = Pipeline(gl_ctx)
    try:
        pipe.set_scene(scene)
        need = max(td.capacity for n, td in pipe.baked.textures.items() if n not in st_mod.ARRAY_ONLY)
        assert pipe.scene_textures.using_buffers
        _, ref = _masks(pipe, scene, Settings(mode="raytrace", hard=True))
        # a GL whose buffer textures hold one texel less than the largest texture: 2D arrays
        monkeypatch.setattr(st_mod, "max_texels", lambda ctx: need - 1)
        pipe.set_scene(scene)
        assert not pipe.scene_textures.using_buffers
        assert not any(isinstance(t, BufferTexture) for t in pipe.scene_textures.textures.values())
        _same(ref, _masks(pipe, scene, Settings(mode="raytrace", hard=True))[1])
        # asked for buffers that cannot hold the scene: one clear error, the pipeline still works
        pipe.scene_textures.buffers = True
        with pytest.raises(GPUError, match=f"needs {need} texels; this GPU's buffer textures hold {need - 1}"):
            pipe.set_scene(scene)
        pipe.scene_textures.buffers = None
        # buffers again once they fit; a model edit that grows a texture past the limit switches
        monkeypatch.setattr(st_mod, "max_texels", lambda ctx: need)
        pipe.set_scene(scene)
        assert pipe.scene_textures.using_buffers
        rng = np.random.default_rng(5)
        old = scene.models[1]
        try:
            scene.models[1] = blob_model(rng, 20000, "big", size=2.0)
            pipe.update_model(scene, 1)
            assert not pipe.scene_textures.using_buffers
            got = _masks(pipe, scene, Settings(mode="raytrace", hard=True))[1]
            fresh = Pipeline(gl_ctx)
            fresh.scene_textures.buffers = False
            fresh.set_scene(scene)
            _same(got, _masks(fresh, scene, Settings(mode="raytrace", hard=True))[1])
            fresh.release()
        finally:
            scene.models[1] = old
    finally:
        pipe.release()


def test_arrays_where_the_gl_will_not_make_a_buffer_texture(gl_ctx, loaded, monkeypatch):
    """A driver that has the entry points but fails to make one (a format it lacks): the scene
    is uploaded as 2D arrays, from then on, and renders the same masks."""
    scene = loaded("alpha_cards")
    pipe = Pipeline(gl_ctx)
    try:
        pipe.set_scene(scene)
        _, ref = _masks(pipe, scene, Settings(mode="raytrace", hard=True))

        def refuse(self, *a, **k):
            raise GPUError("could not create a buffer texture (GL error 0x0500)")
        monkeypatch.setattr(BufferTexture, "__init__", refuse)
        pipe.set_scene(scene)
        assert not pipe.scene_textures.using_buffers and pipe.scene_textures.buffers is False
        _same(ref, _masks(pipe, scene, Settings(mode="raytrace", hard=True))[1])
    finally:
        pipe.release()
