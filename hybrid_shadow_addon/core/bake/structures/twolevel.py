"""Two-level BVH (structure ``"bvh"``, the default): SAH model trees (:mod:`.blas`) under an SAH
tree over the casters' world boxes (:mod:`.tlas`), one 16-bit quantised node per texel; textures
[node] and [leaf] of ``shaders/common/scene_bvh.glsl``.

The top level holds one caster per leaf, boxes = the world box of the model box (or sphere box)
corners, padded by ``TLAS_PAD`` relative, quantised on one grid over the scene. Moves refit the
top level: the moved leaves and their ancestors only, re-packing just those texels (rebuild when
the boxes leave the grid, membership changes or the SAH area doubles); a model edit rebuilds that
model's tree (in place when it fits) and refits. The bake builds the top-level tree on a second
thread while the model trees build (it needs only the model boxes). With ``BVHConfig.wide``
the trees are also packed as 4-wide nodes ([wide], :mod:`.wide`) for the single rays' walk: a
refit copies the changed boxes there, a rebuilt tree packs its blocks again.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

from ...errors import SceneError
from ...limits import check_bake_memory, check_instance_count, out_of_memory
from ...progress import checkpoint
from ..report import UpdateReport
from ..textures import (
    MAX_ROWS_LOG2,
    SPHERE_FLAG,
    TextureData,
    alloc_texture,
    f32_bits,
    f32_up,
    grow_texture,
    rows_of_texels,
    texel_rows,
)
from .base import AccelerationStructure, ModelSlots
from .blas import (
    FORMATS,
    INST_TEXELS,
    LEAF_READ,
    NAMES,
    TLAS_PAD,
    build_blas,
    leaf_size,
    model_box,
    relocate_nodes,
    tri_texels,
)
from .tlas import TopLevel
from .wide import STRIDE, WIDTH, WideIndex

#: [leaf] texels the model trees can address: a leaf node's payload is (first [leaf] texel << 3) |
#: triangle count in the 31 bits below LEAF_FLAG, so its texel must stay below 2^28 (about 119
#: million unique triangles at 2.25 texels each, less 5 texels per instance). Past it the
#: payloads would wrap silently onto other triangles.
MAX_LEAF_TEXELS = 1 << 28


def leaf_texels(triangle_counts, leaf: int) -> int:
    """[leaf] texels of model trees over ``triangle_counts`` (one per model) with ``leaf``
    triangles per leaf: ``leaf`` consecutive triangles per leaf (the last one of a model fewer),
    ``ceil(9 count / 4)`` texels each (:func:`.blas.build_blas`)."""
    tc = np.asarray(triangle_counts, np.int64)
    full, rest = tc // leaf, tc % leaf
    return int((full * tri_texels(leaf)).sum() + tri_texels(rest).sum())


def check_leaf_texels(texels: int, triangles: int, instances: int) -> None:
    """SceneError when the [leaf] texture would need texels past :data:`MAX_LEAF_TEXELS`."""
    if texels > MAX_LEAF_TEXELS:
        raise SceneError(f"the scene's {triangles:,} unique triangles and {instances:,} instances need {texels:,} "
                         f"BVH leaf texels; at most {MAX_LEAF_TEXELS:,} (2^28) can be addressed "
                         f"(about {MAX_LEAF_TEXELS * 4 // 9:,} triangles; instance repeated meshes instead)")


@dataclass
class TreeSlots(ModelSlots):
    """:class:`ModelSlots` (triangles in [leaf] texels) plus each model tree's quantisation
    frame and model-space box."""

    base: np.ndarray = None  # (M, 3) quantisation frame of the model tree
    inv_s: np.ndarray = None  # (M,)
    mbox: np.ndarray = None  # (M, 2, 3) model box float64


class TwoLevelBVH(AccelerationStructure):
    """Model trees under a tree over the instances' world boxes (see the module docstring)."""

    name = "bvh"
    label = "Two-Level BVH"
    description = "SAH tree over the instances whose leaves enter SAH trees per model (compact one-texel nodes)"
    glsl_include = "common/scene_bvh.glsl"
    supports_light_grids = True
    supports_packets = True

    def __init__(self, config, origin, materials):
        super().__init__(config, origin, materials)
        self.tex: dict[str, TextureData] = {}
        self.node_tail = 0  # [node] records allocated
        self.leaf_tail = 0  # [leaf] texels allocated (instance records, then triangle blocks)
        self.models = TreeSlots.empty()
        self.top = TopLevel()
        # per instance
        self.member = np.zeros(0, bool)  # in the top level
        self.sphere_of = np.zeros(0, bool)  # analytic sphere
        self.box_lo = np.zeros((0, 3))  # padded world box, bake space
        self.box_hi = np.zeros((0, 3))
        self.uv_models: np.ndarray | None = None  # (M,) bool: models whose UVs are in "uv"
        self.wide: WideIndex | None = None  # where [wide] copies each [node] texel (``config.bvh.wide``)

    def _new_texture(self, name, n) -> TextureData:
        comps, fmt = FORMATS[name]
        return alloc_texture(name, n, comps, fmt, self.config.tex_width)

    def _grow(self, name, need, rep=None) -> None:
        tex = self.tex[name]
        if grow_texture(tex, need) and rep is not None:
            rep.resized.add(name)
        tex.used = max(tex.used, need)
        if name == "leaf" and "uv" in self.tex:  # the UVs mirror the [leaf] texels
            self._grow("uv", need, rep)

    # ----------------------------------------------------------------------------- bake --
    @classmethod
    def bake(cls, scene, config, origin, materials) -> TwoLevelBVH:
        """The structure of ``scene``; first the limits it must fit (instances, [leaf] texels,
        memory), each a one-line error before anything is built."""
        n = len(scene.instances)
        check_instance_count(n)
        counts = [m.triangle_count for m in scene.models]
        check_leaf_texels(n * INST_TEXELS + leaf_texels(counts, leaf_size(config)) + LEAF_READ, sum(counts), n)
        check_bake_memory(sum(counts), n)
        try:
            return cls._bake(scene, config, origin, materials)
        except MemoryError:  # (past the lower bound checked above: numpy could not allocate)
            raise out_of_memory(sum(counts), n) from None

    @classmethod
    def _bake(cls, scene, config, origin, materials) -> TwoLevelBVH:
        t_start = time.perf_counter()
        self = cls(config, origin, materials)
        models = list(scene.models)
        M = len(models)
        n = len(scene.instances)
        uv_models = scene.alpha_models() if materials is not None and materials.cuts_shadows else None
        inst_end = n * INST_TEXELS
        trees = self.models = TreeSlots.empty(M)
        trees.tri_count = np.array([m.triangle_count for m in models], np.int64)
        trees.mbox = np.zeros((M, 2, 3))
        for m in range(M):
            trees.mbox[m] = model_box(models[m], False)
        self.member = np.zeros(n, bool)
        self.sphere_of = np.zeros(n, bool)
        self.box_lo = np.zeros((n, 3))
        self.box_hi = np.zeros((n, 3))

        # the instance boxes and the top-level tree need only the model boxes: a second thread
        # builds them while this one builds the model trees (numpy releases the GIL in its loops;
        # the two touch disjoint state)
        top = {}

        def plan_top():
            try:
                t1 = time.perf_counter()
                if n:
                    self.write_instance_boxes(scene, np.arange(n))
                top["count"] = self.top.plan(self.member, self.box_lo, self.box_hi)
                top["ms"] = (time.perf_counter() - t1) * 1e3
            except BaseException as e:  # re-raised by the bake
                top["error"] = e

        def alloc(n_tex, want_uv):  # the triangles go straight into [leaf] (and the UVs into "uv")
            tail = inst_end + n_tex
            self.tex["leaf"] = self._new_texture("leaf", tail + LEAF_READ)
            uv4 = None
            if want_uv:
                self.tex["uv"] = self._new_texture("uv", self.tex["leaf"].capacity)
                uv4 = self.tex["uv"].linear()[inst_end:tail]
            return self.tex["leaf"].linear()[inst_end:tail].view(np.float32), uv4

        worker = threading.Thread(target=plan_top, name="hybrid-shadows-tlas", daemon=True)
        t0 = time.perf_counter()
        worker.start()
        try:
            blas = build_blas(models, leaf_size(config), uv_models, alloc)
            blas_ms = (time.perf_counter() - t0) * 1e3
        finally:
            worker.join()
        if "error" in top:
            raise top["error"]
        t0 = time.perf_counter()
        trees.node_start = blas.node_start.copy()
        trees.node_count = blas.node_count.copy()
        trees.node_cap = blas.node_count.copy()
        trees.tri_start = blas.tri_start + inst_end
        trees.tri_cap = blas.tri_texels.copy()
        trees.depth = blas.depth.copy()
        trees.base, trees.inv_s = blas.base.copy(), blas.inv_s.copy()
        self.node_tail = int(blas.node_count.sum())
        self.leaf_tail = inst_end + int(blas.tri_texels.sum())
        self.tex["leaf"].used = self.leaf_tail
        if blas.uv4 is not None:
            self.uv_models = np.asarray(uv_models, bool).copy()
            self.tex["uv"].used = self.leaf_tail
        checkpoint()
        # [node]: model trees, then the top level (with spare room)
        ncast = int(scene.instances.casts_shadow.sum()) if n else 0
        spare = max(1024, int(0.25 * (self.node_tail + 2 * ncast)))
        self.tex["node"] = self._new_texture("node", self.node_tail + 2 * ncast + spare)
        self.tex["node"].used = self.node_tail
        if self.node_tail:
            nodes = self.tex["node"].linear()[: self.node_tail]
            nodes[:] = blas.nodes
            relocate_nodes(nodes, trees.node_start, blas.node_start, blas.node_count, trees.tri_start,
                           blas.tri_start)
        checkpoint()
        if n:
            self.write_instance_records(scene, np.arange(n))
        checkpoint()
        self.place_top(top["count"])
        self.pack_wide(trees.node_start, trees.node_start + trees.node_count)
        self.pack_wide([self.top.start], [self.top.start + self.top.count], refits=True)
        tlas_ms = top["ms"] + (time.perf_counter() - t0) * 1e3  # (its tree overlaps the model trees)
        self.stats = {"bake_ms": (time.perf_counter() - t_start) * 1e3, "blas_ms": blas_ms, "tlas_ms": tlas_ms}
        return self

    # ----------------------------------------------------------------------- instances --
    def write_instances(self, scene, idx) -> None:
        """[leaf] instance records and world boxes of instances ``idx``."""
        self.write_instance_records(scene, idx)
        self.write_instance_boxes(scene, idx)

    @staticmethod
    def sphere_frames(scene, mid, sph) -> np.ndarray:
        """(count of ``sph``, 4) float32 model spheres (centre, radius rounded up) of the
        analytic sphere instances among model ids ``mid``."""
        sphere_models = np.unique(mid[sph])
        sp = np.array([np.concatenate([scene.models[m].sphere_center, f32_up([scene.models[m].sphere_radius])])
                       for m in sphere_models.tolist()], np.float32).reshape(-1, 4)
        return sp[np.searchsorted(sphere_models, mid[sph])]

    def write_instance_records(self, scene, idx) -> None:
        """[leaf] instance records of instances ``idx`` (needs the model trees' places)."""
        inst = scene.instances
        trees = self.models
        idx = np.asarray(idx, np.int64)
        mid = inst.model_ids[idx].astype(np.int64)
        sph = inst.sphere[idx]
        inv = inst.inverse[idx, :3, :].copy()
        inv[:, :, 3] += inv[:, :, :3] @ self.origin
        rec = self.tex["leaf"].linear()[: len(inst) * INST_TEXELS].reshape(-1, INST_TEXELS * 4)
        block = np.zeros((len(idx), INST_TEXELS * 4), np.uint32)
        block[:, 0:12] = f32_bits(inv.reshape(len(idx), 12).astype(np.float32))
        root = trees.node_start[mid]
        block[:, 12] = np.where(sph, 0, root)
        block[:, 13] = np.where(sph, 0, root + trees.node_count[mid])
        block[:, 14] = mid.astype(np.uint32) | np.where(sph, SPHERE_FLAG, np.uint32(0))
        if self.uv_models is not None:  # 1 + material of an alpha-cut caster (its model has UVs), else 0
            slot = self.materials.instance_slots(inst.material_ids[idx])
            block[:, 15] = np.where(self.uv_models[mid] & ~sph, slot, 0)
        frame = np.zeros((len(idx), 4), np.float32)
        frame[:, 0:3] = trees.base[mid]
        frame[:, 3] = trees.inv_s[mid]
        if sph.any():
            frame[sph] = self.sphere_frames(scene, mid, sph)
        block[:, 16:20] = f32_bits(frame)
        rec[idx] = block

    def write_instance_boxes(self, scene, idx) -> None:
        """World boxes (bake space, padded) and top-level membership of instances ``idx`` (needs
        only the model boxes and triangle counts)."""
        inst = scene.instances
        trees = self.models
        idx = np.asarray(idx, np.int64)
        mid = inst.model_ids[idx].astype(np.int64)
        sph = inst.sphere[idx]
        box = np.empty((len(idx), 2, 3))
        box[:] = trees.mbox[mid] if len(trees.mbox) else 0.0
        if sph.any():
            sp = self.sphere_frames(scene, mid, sph)
            c, r = sp[:, 0:3].astype(np.float64), sp[:, 3:4].astype(np.float64)
            box[sph, 0], box[sph, 1] = c - r, c + r
        # world boxes of the model box corners (bake space), padded: corner k maps to
        # ((R[i,0] p0 + R[i,2] p2) + R[i,1] p1 + t_i) - origin_i (the order np.einsum sums in);
        # every rounding step is monotone in each term, so the min / max over the 8 corners is
        # that sum of the per-term min / max (bit for bit, without the (n, 8, 3) corner array)
        Mx = inst.matrices[idx]
        R = Mx[:, :3, :3]
        term_lo = R * box[:, None, 0, :]
        term_hi = R * box[:, None, 1, :]
        mn = np.minimum(term_lo, term_hi)
        mx = np.maximum(term_lo, term_hi)
        t = Mx[:, :3, 3]
        lo = ((((0.0 + mn[:, :, 0]) + mn[:, :, 2]) + mn[:, :, 1]) + t) - self.origin
        hi = ((((0.0 + mx[:, :, 0]) + mx[:, :, 2]) + mx[:, :, 1]) + t) - self.origin
        pad = TLAS_PAD * (np.maximum(np.abs(lo), np.abs(hi)).max(axis=1) + (hi - lo).max(axis=1)) + 1e-30
        self.box_lo[idx] = lo - pad[:, None]
        self.box_hi[idx] = hi + pad[:, None]
        tri = trees.tri_count[mid] > 0 if len(trees.tri_count) else np.zeros(len(idx), bool)
        ok = np.isfinite(lo).all(axis=1) & np.isfinite(hi).all(axis=1)
        self.member[idx] = inst.casts_shadow[idx] & (sph | tri) & ok
        self.sphere_of[idx] = sph

    # ----------------------------------------------------------------------------- wide --
    def fit_wide(self, rep=None) -> None:
        """[wide] (created at the first call) with room for a block at every [node] texel."""
        cap = self.tex["node"].capacity
        need = STRIDE * cap + WIDTH
        if self.wide is None:
            self.tex["wide"] = self._new_texture("wide", need)
            self.wide = WideIndex(cap)
        elif grow_texture(self.tex["wide"], need) and rep is not None:
            rep.resized.add("wide")
        self.tex["wide"].used = need
        self.wide.fit(cap)

    def pack_wide(self, roots, ends, rep=None, refits=False) -> None:
        """[wide] blocks of the trees at [node] ``[roots[k], ends[k])`` (``config.bvh.wide``;
        ``refits``: the top level, which :meth:`refit_wide` follows)."""
        if not self.config.bvh.wide:
            return
        self.fit_wide(rep)
        at = self.wide.pack(self.tex["node"].linear(), self.tex["wide"].linear(), roots, ends, refits)
        if rep is not None and at.size and "wide" not in rep.resized:
            rep.ranges += rows_of_texels("wide", at, self.config.tex_width)

    def refit_wide(self, changed, rep) -> None:
        """The [wide] copies of refitted [node] texels ``changed``."""
        if self.wide is None:
            return
        at = self.wide.refit(self.tex["node"].linear(), self.tex["wide"].linear(), changed)
        if at.size:
            rep.ranges += rows_of_texels("wide", at, self.config.tex_width)

    # ------------------------------------------------------------------------ top level --
    def alloc_top_nodes(self, n) -> tuple[int, bool]:
        """[node] records for the top level: in place when it fits, else at the tail."""
        top = self.top
        grown = False
        if n <= top.cap and top.cap:
            return top.start, False
        start = self.node_tail
        self.node_tail += n
        top.cap = n
        tex = self.tex["node"]
        if self.node_tail > tex.capacity:
            grown = grow_texture(tex, self.node_tail + 1024)
        tex.used = max(tex.used, self.node_tail)
        return start, grown

    def place_top(self, count) -> bool:
        """[node] records for the planned top level of ``count`` nodes, and its texels. True
        when [node] was resized."""
        start, grown = self.alloc_top_nodes(count)
        self.top.start, self.top.count = start, count
        self.top.write(self.tex["node"])
        return grown

    def build_top(self) -> bool:
        """(Re)build the top level over the member instances. True when [node] was resized."""
        return self.place_top(self.top.plan(self.member, self.box_lo, self.box_hi))

    # -------------------------------------------------------------------------- updates --
    def ensure_uvs(self, scene, models, rep: UpdateReport) -> None:
        """Store the UVs of ``models`` that now need them (an instance of theirs got an alpha-cut
        material since the bake): the "uv" texture is created when the bake had none."""
        if self.materials is None:
            return  # no material records baked: a scene with new materials needs a new bake
        need = scene.alpha_models()
        todo = [m for m in models if m < len(need) and need[m] and (self.uv_models is None or not self.uv_models[m])]
        if not todo:
            return
        W = self.config.tex_width
        if self.uv_models is None:
            self.uv_models = np.zeros(len(self.models), bool)
            self.tex["uv"] = self._new_texture("uv", self.tex["leaf"].capacity)
            self.tex["uv"].used = self.leaf_tail
            rep.resized.add("uv")
        for m in todo:
            self.uv_models[m] = True
            # the same build as the baked tree (deterministic): its triangles sit in the same order
            blas = build_blas([scene.models[m]], leaf_size(self.config), np.array([True]))
            first, texels = int(self.models.tri_start[m]), int(blas.tri_texels[0])
            if blas.uv4 is not None and texels:
                self.tex["uv"].linear()[first:first + texels] = blas.uv4
                rep.ranges += texel_rows("uv", first, first + texels, W)

    def update_instances(self, scene, indices) -> UpdateReport:
        rep = UpdateReport()
        idx = np.unique(np.asarray(indices, np.int64).reshape(-1))
        if idx.size == 0:
            return rep
        if len(scene.instances) != len(self.member):
            raise ValueError("instances were added or removed: bake the scene again")
        W = self.config.tex_width
        top = self.top
        old_member = self.member[idx].copy()
        old_uniforms = top.uniforms()
        old_defines = self.defines
        self.ensure_uvs(scene, np.unique(scene.instances.model_ids[idx]).tolist(), rep)
        self.write_instances(scene, idx)
        rep.ranges += rows_of_texels("leaf", (idx[:, None] * INST_TEXELS + np.arange(INST_TEXELS)).ravel(), W)
        rep.objects += int(idx.size)
        mem = self.member[idx]
        moved = idx[mem]
        rebuild = bool((mem != old_member).any()) or not top.holds(self.box_lo[moved], self.box_hi[moved])
        if not rebuild:
            refit = top.refit(idx, self.box_lo, self.box_hi)
            if top.degraded():
                rebuild = True
            else:
                changed = top.write(self.tex["node"], refit)
                rep.ranges += rows_of_texels("node", changed, W)
                self.refit_wide(changed, rep)
                rep.nodes_changed += int(changed.size)
        if rebuild:
            grown = self.build_top()
            rep.regrid = True
            if grown:
                rep.resized.add("node")
            else:
                rep.ranges += texel_rows("node", top.start, top.start + top.count, W)
            self.pack_wide([top.start], [top.start + top.count], rep, refits=True)
            rep.nodes_changed += top.count
        new_uniforms = top.uniforms()
        if any(not np.array_equal(new_uniforms[k], old_uniforms[k]) for k in new_uniforms):
            rep.uniforms_changed = True
        if self.defines != old_defines:
            rep.defines_changed = True
        return self.finish_update(rep)

    def append_model(self, rep: UpdateReport) -> None:
        self.models.append()

    def rebuild_model(self, scene, m: int, rep: UpdateReport) -> None:
        W = self.config.tex_width
        trees = self.models
        uvm = None
        if self.uv_models is not None:
            if m == len(self.uv_models):
                self.uv_models = np.concatenate([self.uv_models, [False]])
            self.uv_models[m] = bool(scene.alpha_models()[m]) and self.materials is not None
            uvm = self.uv_models[m:m + 1]
        blas = build_blas([scene.models[m]], leaf_size(self.config), uvm)
        nc, texels = int(blas.node_count[0]), int(blas.tri_texels[0])
        if nc > trees.node_cap[m] or texels > trees.tri_cap[m]:  # (it goes to the tails: check before)
            check_leaf_texels(self.leaf_tail + texels + LEAF_READ,
                              int(trees.tri_count.sum()) - int(trees.tri_count[m]) + int(blas.tri_count[0]),
                              len(self.member))
        node_base, tri_base, at_tail = trees.place(m, nc, texels, self.node_tail, self.leaf_tail)
        if at_tail:
            self.node_tail += nc
            self.leaf_tail += texels
            self._grow("node", self.node_tail, rep)
            self._grow("leaf", self.leaf_tail + LEAF_READ, rep)
        trees.node_start[m], trees.node_count[m] = node_base, nc
        trees.tri_start[m], trees.tri_count[m] = tri_base, int(blas.tri_count[0])
        trees.depth[m] = int(blas.depth[0])
        trees.base[m], trees.inv_s[m] = blas.base[0], blas.inv_s[0]
        trees.mbox[m] = model_box(scene.models[m], False)
        if nc:
            nodes = blas.nodes.copy()
            relocate_nodes(nodes, np.array([node_base]), blas.node_start, blas.node_count, np.array([tri_base]),
                           blas.tri_start)
            self.tex["node"].linear()[node_base:node_base + nc] = nodes
            self.tex["leaf"].linear()[tri_base:tri_base + texels] = blas.tri4.view(np.uint32)
            if blas.uv4 is not None:
                self.tex["uv"].linear()[tri_base:tri_base + texels] = blas.uv4
        rep.ranges += texel_rows("node", node_base, node_base + nc, W)
        rep.ranges += texel_rows("leaf", tri_base, tri_base + texels, W)
        self.pack_wide([node_base], [node_base + nc], rep)
        if blas.uv4 is not None:
            rep.ranges += texel_rows("uv", tri_base, tri_base + texels, W)
        self.ensure_uvs(scene, [m], rep)

    # ------------------------------------------------------------------------ read-outs --
    @property
    def textures(self) -> dict[str, TextureData]:
        return {n: self.tex[n] for n in NAMES if n in self.tex}

    @property
    def has_meshes(self) -> bool:
        return bool((self.member & ~self.sphere_of).any()) if len(self.member) else False

    @property
    def has_spheres(self) -> bool:
        return bool((self.member & self.sphere_of).any()) if len(self.member) else False

    @property
    def has_alpha(self) -> bool:
        return self.uv_models is not None and self.has_meshes

    @property
    def defines(self) -> dict:
        w = int(self.config.tex_width)
        d = {"HS_STRUCTURE_BVH": 1, "HS_TEX_WIDTH": w, "HS_TEX_WIDTH_LOG2": w.bit_length() - 1,
             "HS_TEX_ROWS_LOG2": MAX_ROWS_LOG2, "HS_BVH_LEAF_SIZE": leaf_size(self.config)}
        if self.has_meshes:
            d["HS_HAS_MESHES"] = 1
        if self.has_spheres:
            d["HS_HAS_SPHERES"] = 1
        if self.has_alpha:
            d["HS_HAS_ALPHA"] = 1
        if self.wide is not None:
            d["HS_BVH_WIDE"] = 1
        return d

    @property
    def uniforms(self) -> dict:
        return self.top.uniforms()

    def refresh_stats(self) -> dict:
        trees = self.models
        self.stats.update({
            "structure": "bvh",
            "instances": int(len(self.member)),
            "casters": int(self.member.sum()),
            "models": int(len(trees)),
            "triangles": int(trees.tri_count.sum()),
            "bvh_nodes": int(trees.node_count.sum()),
            "bvh_max_depth": int(trees.depth.max()) if len(trees.depth) else 0,
            "tlas_nodes": int(self.top.count),
            "tlas_max_depth": int(self.top.depth.max()) if len(self.top.depth) else 0,
        })
        return self.stats

    def occupancy(self, xy: np.ndarray) -> np.ndarray:
        """The casters whose top-level (world) box covers each point in x and y: how many
        instances a vertical ray through it would have to consider."""
        return self.top.column_counts(np.asarray(xy, np.float64).reshape(-1, 2))
