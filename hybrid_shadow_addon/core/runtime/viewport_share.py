"""What the viewports of one scene share (bpy-free): every engine instance gets the same
depsgraph updates (:class:`UpdateRounds`: each is applied once); the state of a scene, one
:class:`~.worker.RenderWorker` and one scene sync (:class:`SharedViewport`), is shared and
reference-counted by its users (:class:`SharedRegistry`)."""
from __future__ import annotations

from typing import TYPE_CHECKING

from .worker import snapshot

if TYPE_CHECKING:
    from .worker import RenderWorker


class UpdateRounds:
    """Which users (engine instances) consumed the current update: every viewport's engine
    receives the same ``depsgraph.updates``; only the first applies them. ``key`` identifies
    an update (the depsgraph evaluation and what changed). A user calling again starts a new
    round even with an equal key (a genuine second edit of the same thing)."""

    def __init__(self):
        self.key = None
        self.consumed: set = set()

    def should_apply(self, user, key) -> bool:
        if user not in self.consumed and key == self.key:
            self.consumed.add(user)
            return False
        self.key = key
        self.consumed = {user}
        return True

    def forget(self, user) -> None:
        self.consumed.discard(user)


class SharedViewport:
    """What the viewports of one scene share: one :class:`RenderWorker` (one context, one bake)
    and one scene sync (``sync.scene``, ``sync.update(depsgraph)`` returning a plan with
    ``nothing``). ``generation`` counts the applied changes, so each viewport knows when to
    render again."""

    def __init__(self, worker: RenderWorker, sync):
        self.worker = worker
        self.sync = sync
        self.generation = 0
        self.rounds = UpdateRounds()
        self._snap = None
        self._snap_generation = -1

    def update(self, user, key, depsgraph):
        """Apply ``depsgraph``'s updates unless another user already did for this ``key``;
        returns the plan applied, or None when skipped."""
        if not self.rounds.should_apply(user, key):
            return None
        plan = self.sync.update(depsgraph)
        if not plan.nothing:
            self.changed()
        return plan

    def changed(self) -> None:
        """The sync's scene changed (outside :meth:`update` too, e.g. its first export)."""
        self.generation += 1

    def scene_snapshot(self):
        """A :func:`snapshot` of the sync's scene, taken again only after a change."""
        if self._snap_generation != self.generation or self._snap is None:
            self._snap = snapshot(self.sync.scene)
            self._snap_generation = self.generation
        return self._snap

    def leave(self, user) -> None:
        self.rounds.forget(user)
        self.worker.drop_view(user)

    def close(self) -> None:
        """Stop the worker, waiting 1 s at most (a frame or bake under way ends on its own, then
        the thread releases the context): an engine freed meanwhile must not freeze the UI."""
        self.worker.close(timeout=1.0)


class SharedRegistry:
    """Shared states by key (a scene, its view layer and local view), reference-counted by
    their users; :meth:`release` by the last user closes one."""

    def __init__(self):
        self._entries: dict = {}  # key -> [state, set of users]
        self._keys: dict = {}  # user -> key

    def acquire(self, user, key, make):
        """The state of ``key`` for ``user`` (made by ``make()`` for its first user); a user
        moving to another key leaves its old one first."""
        old = self._keys.get(user)
        if old == key and key in self._entries:
            return self._entries[key][0]
        if old is not None:
            self.release(user)
        entry = self._entries.get(key)
        if entry is None:
            entry = self._entries[key] = [make(), set()]
        entry[1].add(user)
        self._keys[user] = key
        return entry[0]

    def get(self, user):
        key = self._keys.get(user)
        return None if key is None else self._entries[key][0]

    def release(self, user) -> bool:
        """``user`` is done; True when that closed the state (it was the last user)."""
        key = self._keys.pop(user, None)
        if key is None:
            return False
        state, users = self._entries[key]
        users.discard(user)
        if hasattr(state, "leave"):
            state.leave(user)
        if users:
            return False
        del self._entries[key]
        state.close()
        return True

    def release_all(self) -> None:
        for state, _ in list(self._entries.values()):
            state.close()
        self._entries.clear()
        self._keys.clear()

    def users(self, user=None):
        """The users sharing ``user``'s state (every user when None)."""
        if user is None:
            return set(self._keys)
        key = self._keys.get(user)
        return set() if key is None else set(self._entries[key][1])

    def states(self) -> list:
        return [state for state, _ in self._entries.values()]

    def __len__(self) -> int:
        return len(self._entries)
