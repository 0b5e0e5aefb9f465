"""Light and shadow linking on the GPU (``shaders/common/linking.glsl``): the instances'
membership words in a texture of their own, indexed by instance, so that a change of the
linking collections is one upload and never a bake; each light's sets as uniforms (the ray pass)
or a one-row texture (the lighting pass). A scene without linking uploads nothing and compiles
none of it (no ``HS_LINKING``)."""
from __future__ import annotations

import moderngl
import numpy as np

from ..scene.linking import membership_words, uses_linking

WIDTH_LOG2 = 10  # texels per row of the membership texture (HS_LINK_WIDTH_LOG2)
WIDTH = 1 << WIDTH_LOG2


class LinkTextures:
    """The membership texture of the last scene :meth:`update` saw, and what binds it."""

    def __init__(self, ctx: moderngl.Context):
        self.ctx = ctx
        self.active = False
        self.uploads = 0  # membership uploads so far (tests: a change is an upload, not a bake)
        self._tex = None
        self._words = None
        self._lights_tex = None

    def update(self, scene) -> bool:
        """Follow ``scene``'s linking; True where the membership texture was (re)written."""
        self.active = uses_linking(scene)
        if not self.active:
            return False
        words = membership_words(scene.instances)
        if self._words is not None and np.array_equal(words, self._words):
            return False
        rows = max(1, -(-len(words) // WIDTH))
        data = np.zeros((rows * WIDTH, 4), np.uint32)
        data[:len(words)] = words
        if self._tex is None or self._tex.size != (WIDTH, rows):
            if self._tex is not None:
                self._tex.release()
            self._tex = self.ctx.texture((WIDTH, rows), 4, dtype="u4")
            self._tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self._tex.write(data.tobytes())
        self._words = words
        self.uploads += 1
        return True

    @property
    def defines(self) -> dict:
        return {"HS_LINKING": 1} if self.active else {}

    @staticmethod
    def light_uniforms(light) -> dict:
        """The ray pass's uniforms of ``light``: its receiver and blocker sets."""
        return {"u_link_receiver": int(light.receiver_set), "u_link_blocker": int(light.blocker_set)}

    def bind(self, prog, unit: int) -> int:
        """Bind the membership texture where ``prog`` reads it; the next free unit."""
        if self.active and self._tex is not None and "hs_link_tex" in prog:
            self._tex.use(unit)
            prog["hs_link_tex"].value = unit
            unit += 1
        return unit

    def bind_lights(self, prog, unit: int, lights) -> int:
        """Bind the receiver sets of ``lights`` (the lighting pass's table rows, in order) and
        the membership texture; the next free unit."""
        if not self.active or "hs_link_lights_tex" not in prog:
            return unit
        sets = np.array([int(light.receiver_set) for light in lights] or [-1], np.int32)
        if self._lights_tex is None or self._lights_tex.size != (len(sets), 1):
            if self._lights_tex is not None:
                self._lights_tex.release()
            self._lights_tex = self.ctx.texture((len(sets), 1), 1, dtype="i4")
            self._lights_tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self._lights_tex.write(sets.tobytes())
        self._lights_tex.use(unit)
        prog["hs_link_lights_tex"].value = unit
        return self.bind(prog, unit + 1)

    def release(self) -> None:
        for tex in (self._tex, self._lights_tex):
            if tex is not None:
                tex.release()
        self._tex = self._lights_tex = self._words = None
        self.active = False
