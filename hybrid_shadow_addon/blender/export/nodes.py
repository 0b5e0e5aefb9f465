"""Following links in a shader node graph as Blender evaluates it: through reroutes and into and
out of node groups, so that a set-up nested in groups reads as the same set-up flat."""
from __future__ import annotations

from typing import NamedTuple

#: Rec. 709 luminance: how Blender turns a colour into a float (a Color socket linked to a Fac)
LUMA = (0.2126, 0.7152, 0.0722)
#: Links followed before giving up (a loop through groups)
MAX_HOPS = 256


class Source(NamedTuple):
    """What feeds an input: ``node``'s output ``socket`` (None when nothing does: ``socket`` is
    then the unlinked input whose default value applies), inside the groups ``stack`` (the group
    nodes entered on the way, innermost last)."""

    node: object
    socket: object
    stack: tuple = ()


def _group_output(tree):
    """The active Group Output node of a node group's tree, else its first, else None."""
    outs = [n for n in tree.nodes if n.type == "GROUP_OUTPUT"]
    return next((n for n in outs if getattr(n, "is_active_output", False)), outs[0] if outs else None)


def _by_identifier(sockets, identifier: str):
    return next((s for s in sockets if s.identifier == identifier), None)


def resolve(socket, stack: tuple = ()) -> Source:
    """The node output feeding input ``socket`` (of a node inside the groups ``stack``): through
    reroutes, into a group node's tree and out of its Group Input back to the group node's
    input. A muted link, or a group without a tree, counts as unlinked (as Blender reads it)."""
    for _ in range(MAX_HOPS):
        if not socket.is_linked:
            return Source(None, socket, stack)
        link = socket.links[0]
        if link.is_muted or not getattr(link, "is_valid", True):
            return Source(None, socket, stack)
        node, out = link.from_node, link.from_socket
        if node.type == "REROUTE":
            socket = node.inputs[0]
            continue
        if node.type == "GROUP" and not node.mute:
            tree = node.node_tree
            gout = _group_output(tree) if tree is not None else None
            inner = _by_identifier(gout.inputs, out.identifier) if gout is not None else None
            if inner is None:
                return Source(None, socket, stack)
            socket, stack = inner, stack + (node,)
            continue
        if node.type == "GROUP_INPUT" and stack:
            outer = _by_identifier(stack[-1].inputs, out.identifier)
            if outer is None:
                return Source(None, socket, stack)
            socket, stack = outer, stack[:-1]
            continue
        return Source(node, out, stack)
    return Source(None, socket, stack)


def constant(socket, stack: tuple = ()):
    """The constant an input reads: its default value when unlinked (through groups), a Value or
    RGB node's value; None when anything else feeds it."""
    src = resolve(socket, stack)
    if src.node is None:
        value = getattr(src.socket, "default_value", None)
    elif src.node.type in ("VALUE", "RGB") and not src.node.mute:
        value = src.socket.default_value
    else:
        return None
    if value is None:
        return None
    try:
        return tuple(float(v) for v in value)
    except TypeError:
        return float(value)


def as_float(value) -> float:
    """A constant as a float socket reads it (a colour through Rec. 709 luminance)."""
    if isinstance(value, tuple):
        return float(sum(c * w for c, w in zip(value[:3], LUMA)))
    return float(value)


def as_rgb(value) -> tuple:
    """A constant as a colour socket reads it (a float as grey)."""
    if isinstance(value, tuple):
        return tuple(float(c) for c in value[:3])
    return (float(value),) * 3


def describe(node) -> str:
    """A node as the export report names it: ``'name' (bl_idname)``."""
    return f"'{node.name}' ({node.bl_idname})"
