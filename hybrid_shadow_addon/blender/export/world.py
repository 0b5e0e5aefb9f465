"""The world's background colour (the ambient light of the scene model)."""
from __future__ import annotations

import numpy as np


def world_background(world):
    """The Background node the world's output uses (else the tree's first), or None."""
    if world is None or not world.use_nodes or not world.node_tree:
        return None
    out = world.node_tree.get_output_node("ALL")
    if out is not None and out.inputs["Surface"].is_linked:
        node = out.inputs["Surface"].links[0].from_node
        if node.type == "BACKGROUND":
            return node
    return next((n for n in world.node_tree.nodes if n.type == "BACKGROUND"), None)


def world_color(world) -> np.ndarray:
    """Linear RGB of the world: its Background node's colour × strength, else ``world.color``."""
    if world is None:
        return np.zeros(3, np.float32)
    bg = world_background(world)
    if bg is not None:
        rgb = np.array(bg.inputs["Color"].default_value[:3], np.float32)
        return rgb * np.float32(bg.inputs["Strength"].default_value)
    return np.array(world.color[:3], np.float32)
