"""Which objects of a depsgraph are rendered: a viewport depsgraph also holds objects hidden from
render, which an export of what F12 renders drops."""
from __future__ import annotations


class RenderVisibility:
    """Whether an original object is rendered: for a viewport depsgraph (when asked), not hidden
    from render itself or through all of its collections; a render depsgraph holds only
    renderable objects. Answers are cached per object."""

    def __init__(self, depsgraph, render_visibility: bool | None = None):
        self.depsgraph = depsgraph
        self.check = (depsgraph.mode != "RENDER" if render_visibility is None
                      else bool(render_visibility) and depsgraph.mode != "RENDER")
        self.renderable_of: dict = {}  # original object pointer -> bool
        self.hidden_collections = None

    def __call__(self, ob) -> bool:
        if not self.check:
            return True
        key = ob.as_pointer()
        ok = self.renderable_of.get(key)
        if ok is None:
            if self.hidden_collections is None:
                self.hidden_collections = set()
                for coll in self.depsgraph.scene.collection.children_recursive:
                    if coll.hide_render:
                        self.hidden_collections.add(coll.as_pointer())
                        self.hidden_collections.update(c.as_pointer() for c in coll.children_recursive)
            colls = [c.as_pointer() for c in ob.users_collection]
            ok = not ob.hide_render and not (colls and all(c in self.hidden_collections for c in colls))
            self.renderable_of[key] = ok
        return ok
