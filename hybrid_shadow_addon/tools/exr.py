"""EXR files through the OpenImageIO Python module that Blender ships (``OpenEXR`` only as a
fallback where it is installed), so that reading Cycles' multilayer EXRs needs nothing added
to Blender's Python.

Blender puts OpenImageIO on ``sys.path``; the ``bpy`` wheel keeps it in its own
``<version>/python/lib/python3.x/site-packages``, where :func:`open_image_io` loads it from when the
plain import fails."""
from __future__ import annotations

import glob
import importlib
import importlib.machinery
import importlib.util
import os
import sys

import numpy as np

#: channel suffixes grouped into one (H, W, C) array, in this order (as OpenEXR's reader does)
COLOUR_SUFFIXES = ("R", "G", "B", "A")


def _bundled_site_packages() -> list:
    """The ``site-packages`` folders of the Python that the ``bpy`` package ships beside itself."""
    spec = importlib.util.find_spec("bpy") if "bpy" not in sys.modules else None
    origin = getattr(sys.modules.get("bpy"), "__file__", None) or (spec.origin if spec else None)
    if not origin:
        return []
    root = os.path.dirname(os.path.abspath(origin))
    if os.path.basename(root) == "bpy" and os.path.basename(os.path.dirname(root)) == "modules":
        root = os.path.dirname(os.path.dirname(os.path.dirname(root)))  # <version>/scripts/modules/bpy
    else:
        root = os.path.join(root, "*")  # the package folder: bpy/<version>/...
    return sorted(glob.glob(os.path.join(root, "python", "lib", "python3*", "site-packages"))
                  + glob.glob(os.path.join(root, "python", "lib", "site-packages")))


def open_image_io():
    """The ``OpenImageIO`` module, from ``sys.path`` or the ``bpy`` package's own Python; None
    where neither has it."""
    try:
        return importlib.import_module("OpenImageIO")
    except ImportError:
        if "OpenImageIO" in sys.modules:  # None there: the import is blocked (as for a package not installed)
            return None
    for folder in _bundled_site_packages():
        spec = importlib.machinery.PathFinder.find_spec("OpenImageIO", [folder])
        if spec is None:
            continue
        module = importlib.util.module_from_spec(spec)
        sys.modules["OpenImageIO"] = module  # (its extension module imports as a submodule)
        try:
            spec.loader.exec_module(module)
        except ImportError:
            del sys.modules["OpenImageIO"]
            continue
        return module
    return None


def _open_exr():
    try:
        return importlib.import_module("OpenEXR")
    except ImportError:
        return None


def can_read_exr() -> bool:
    """Whether :func:`read_exr` has a module to read with."""
    return open_image_io() is not None or _open_exr() is not None


def group_channels(names: list, pixels: np.ndarray) -> dict:
    """``{name: (H, W[, C])}`` from the channel names and the (H, W, N) pixels of one image:
    ``layer.R``, ``layer.G``... in that order become one ``layer`` array; every other channel
    stays on its own under its full name."""
    out, i = {}, 0
    while i < len(names):
        layer, _, suffix = names[i].rpartition(".")
        n = 0
        while (i + n < len(names) and n < len(COLOUR_SUFFIXES)
               and names[i + n] == (f"{layer}.{COLOUR_SUFFIXES[n]}" if layer else COLOUR_SUFFIXES[n])):
            n += 1
        if n >= 3:
            out[layer or "RGBA"[:n]] = np.ascontiguousarray(pixels[..., i:i + n], np.float32)
            i += n
        else:
            out[names[i]] = np.ascontiguousarray(pixels[..., i], np.float32)
            i += 1
    return out


def _read_oiio(oiio, path: str) -> dict:
    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise OSError(f"cannot read {path}: {oiio.geterror()}")
    out = {}
    try:
        sub = 0
        while inp.seek_subimage(sub, 0):
            spec = inp.spec()
            px = np.asarray(inp.read_image("float"), np.float32)
            px = px.reshape(spec.height, spec.width, spec.nchannels)
            out.update(group_channels(list(spec.channelnames), px))
            sub += 1
    finally:
        inp.close()
    return out


def _read_openexr(openexr, path: str) -> dict:
    out = {}
    with openexr.File(path, separate_channels=False) as f:
        for part in f.parts:
            for name, ch in part.channels.items():
                out[name] = np.asarray(ch.pixels, dtype=np.float32)
    return out


def read_exr(path: str) -> dict:
    """All channels of a (multi-part, multi-layer) EXR as ``{name: (H, W[, C]) float32}``, row 0
    the top row; colour channels grouped as :func:`group_channels` says."""
    oiio = open_image_io()
    if oiio is not None:
        return _read_oiio(oiio, path)
    openexr = _open_exr()
    if openexr is not None:
        return _read_openexr(openexr, path)
    raise ImportError("reading EXR files needs the OpenImageIO module that Blender ships (or OpenEXR)")


def write_exr(path: str, rgba: np.ndarray) -> None:
    """Linear float (H, W, 4) RGBA EXR, row 0 the top row, zip compressed."""
    a = np.ascontiguousarray(rgba, dtype=np.float32)
    oiio = open_image_io()
    if oiio is not None:
        spec = oiio.ImageSpec(a.shape[1], a.shape[0], a.shape[2], "float")
        spec.attribute("compression", "zip")
        out = oiio.ImageOutput.create(path)
        if out is None or not out.open(path, spec) or not out.write_image(a) or not out.close():
            raise OSError(f"cannot write {path}: {oiio.geterror()}")
        return
    openexr = _open_exr()
    if openexr is None:
        raise ImportError("writing EXR files needs the OpenImageIO module that Blender ships (or OpenEXR)")
    header = {"compression": openexr.ZIP_COMPRESSION, "type": openexr.scanlineimage}
    with openexr.File(header, {"RGBA": a}) as f:
        f.write(path)
