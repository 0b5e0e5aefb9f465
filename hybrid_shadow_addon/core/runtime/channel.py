"""The renderer process's channel: pickled messages over a pair of pipes, and errors that cross it.

A message is a header (the pickle's length, the number of out-of-band buffers and each one's
length), the pickle (protocol 5) and the buffers: numpy arrays travel out of band, read straight
into their own memory without a second copy. Reads and writes go through file objects whose
system calls release Python's lock, so a thread waiting on the channel never holds it.
"""
from __future__ import annotations

import pickle
import struct
import traceback

from .. import errors as _errors

_HEAD = struct.Struct("<QI")
_SIZE = struct.Struct("<Q")


def encode_message(obj) -> list:
    """``obj`` as the pieces :func:`write_encoded` writes. Whatever pickling raises (a message
    that cannot cross) comes from here, before anything is written."""
    bufs: list = []
    meta = pickle.dumps(obj, protocol=5, buffer_callback=bufs.append)
    raws = [b.raw() for b in bufs]
    return [_HEAD.pack(len(meta), len(raws)) + b"".join(_SIZE.pack(r.nbytes) for r in raws) + meta, *raws]


def write_encoded(f, pieces: list) -> None:
    """Write :func:`encode_message`'s pieces to the binary file ``f`` and flush (``OSError`` or
    ``ValueError``: the other side is gone)."""
    for piece in pieces:
        f.write(piece)
    f.flush()


def write_message(f, obj) -> None:
    """Write ``obj`` to the binary file ``f`` and flush."""
    write_encoded(f, encode_message(obj))


def _read_exact(f, n: int) -> bytearray:
    out = bytearray(n)
    view = memoryview(out)
    got = 0
    while got < n:
        k = f.readinto(view[got:])
        if not k:
            raise EOFError("the renderer process closed its channel")
        got += k
    return out


def read_message(f):
    """The next message from the binary file ``f``; EOFError when the other side is gone."""
    n_meta, n_bufs = _HEAD.unpack(_read_exact(f, _HEAD.size))
    sizes = struct.unpack(f"<{n_bufs}Q", _read_exact(f, _SIZE.size * n_bufs)) if n_bufs else ()
    meta = _read_exact(f, n_meta)
    bufs = [_read_exact(f, s) for s in sizes]
    return pickle.loads(meta, buffers=bufs)


def error_info(exc: BaseException) -> tuple:
    """``(class name, message, traceback text)`` of an exception, for the other side."""
    tb = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
    return type(exc).__name__, str(exc), tb


class RendererError(_errors.HybridShadowError):
    """The renderer process failed (it ended, or a bug there): the message says what."""


def rebuild_error(info: tuple) -> BaseException:
    """The caller's exception for an :func:`error_info`: the project's user-facing errors and
    ``ValueError`` keep their class and message; anything else is a :class:`RendererError`
    carrying the class name and the remote traceback (``remote_traceback``)."""
    name, message, tb = info
    cls = getattr(_errors, name, None)
    if isinstance(cls, type) and issubclass(cls, _errors.HybridShadowError):
        exc = cls(message)
    elif name == "ValueError":
        exc = ValueError(message)
    elif name == "RendererError":
        exc = RendererError(message)
    else:
        exc = RendererError(f"{name}: {message}")
    exc.remote_traceback = tb
    return exc
