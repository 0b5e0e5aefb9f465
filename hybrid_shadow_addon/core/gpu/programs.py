"""GLSL programs from ``shaders/<name>.glsl``: one file holds all stages.

Each stage is compiled from the same file with ``#define VERTEX_SHADER``, ``FRAGMENT_SHADER``
(or ``GEOMETRY_SHADER``) prepended, moderngl-window style; a stage is built only when its name
appears in the file. A file with a ``COMPUTE_SHADER`` section is also a compute program
(:meth:`ProgramCache.compute`, ``#version 430 core``: contexts of GL 4.3 and newer). The source
gets ``#version 410 core`` and the sorted defines first, and
``#include "common/x.glsl"`` lines (relative to ``shaders/``) are resolved recursively, each file
once. A ``#line`` directive per file numbers file k's lines from ``k * 100000 + 1``, so the
driver's log maps back to ``file:line`` in the error.

Programs are cached by (name, defines, varyings). With ``HS_RECORD_DEFINES=/path/file.jsonl`` in
the environment, each distinct program of ``shaders/`` built is appended to that file once, as
``{"program", "defines", "varyings"}`` (compute programs with ``"stage": "COMPUTE_SHADER"``):
``tools/shader_check.py`` compiles those sets again.
"""
from __future__ import annotations

import json
import os
import re
from pathlib import Path

import moderngl

from ..errors import GPUError

GLSL_VERSION = "#version 410 core"
COMPUTE_VERSION = "#version 430 core"
COMPUTE_GL = 430  # the context version that compute programs need
STAGES = ("VERTEX_SHADER", "GEOMETRY_SHADER", "FRAGMENT_SHADER")
COMPUTE = "COMPUTE_SHADER"
_LINE_STRIDE = 100000
_INCLUDE = re.compile(r'^\s*#\s*include\s+"([^"]+)"\s*(?://.*)?$')
_BRANCH = re.compile(r"^\s*#\s*(else|elif|endif)\b")


def default_shader_dir() -> Path:
    """``<root>/shaders``: ``hybrid_shadow_addon/`` and ``shaders/`` are siblings."""
    pkg = Path(__file__).resolve().parents[2]  # hybrid_shadow_addon/
    for cand in (pkg.parent / "shaders", pkg / "shaders"):
        if cand.is_dir():
            return cand
    return pkg.parent / "shaders"


class ShaderError(GPUError):
    """A shader is missing or does not compile/link."""


_ONLY_WITH = re.compile(r"^//\s*(\w+_SHADER) only with (\w+)", re.MULTILINE)


def program_stages(text: str, defines=()) -> list[str]:
    """The stages built from a program file's text under ``defines`` (names or ``(name, value)``
    pairs): those whose name appears in it, except a stage the file builds only with a define
    (a line ``// GEOMETRY_SHADER only with NAME``) while that define is absent."""
    names = {d[0] if isinstance(d, tuple) else d for d in defines}
    only = {stage: define for stage, define in _ONLY_WITH.findall(text)}
    return [stage for stage in STAGES if stage in text and (stage not in only or only[stage] in names)]


_recorded: set = set()


def _record(name: str, defines: tuple, varyings, stage: str | None = None) -> None:
    """Append one built program to ``$HS_RECORD_DEFINES`` (once per process and key)."""
    target = os.environ.get("HS_RECORD_DEFINES")
    key = (name, defines, tuple(varyings or ()), stage)
    if not target or key in _recorded:
        return
    _recorded.add(key)
    rec = {"program": name, "defines": dict(defines), "varyings": list(key[2])}
    if stage is not None:
        rec["stage"] = stage
    line = json.dumps(rec)
    with open(target, "a", encoding="utf-8") as out:
        out.write(line + "\n")


class ProgramCache:
    """Compiles and caches the programs of one context."""

    def __init__(self, ctx: moderngl.Context, shader_dir: str | Path | None = None):
        self.ctx = ctx
        self.shader_dir = Path(shader_dir) if shader_dir is not None else default_shader_dir()
        self._programs: dict = {}
        self._vaos: dict = {}

    # -- public ----------------------------------------------------------------------------
    def get(self, name: str, defines: dict | None = None, varyings=None) -> moderngl.Program:
        frozen = tuple(sorted((str(k), _define_value(v)) for k, v in (defines or {}).items()))
        key = (name, frozen, tuple(varyings) if varyings else ())
        prog = self._programs.get(key)
        if prog is None:
            prog = self._build(name, frozen, varyings)
            self._programs[key] = prog
        return prog

    def compute(self, name: str, defines: dict | None = None) -> moderngl.ComputeShader:
        """The compute program of ``shaders/<name>.glsl``'s ``COMPUTE_SHADER`` section."""
        frozen = tuple(sorted((str(k), _define_value(v)) for k, v in (defines or {}).items()))
        key = (name, frozen, COMPUTE)
        prog = self._programs.get(key)
        if prog is None:
            prog = self._programs[key] = self._build_compute(name, frozen)
        return prog

    def fullscreen(self, name: str, defines: dict | None = None):
        """``(program, vao)`` for a full-screen pass: draw with ``vao.render(vertices=3)``.

        The shader's vertex stage should ``#include "common/fullscreen.glsl"`` (a buffer-less
        triangle from ``gl_VertexID``)."""
        prog = self.get(name, defines)
        vao = self._vaos.get(id(prog))
        if vao is None:
            vao = self.ctx.vertex_array(prog, [])
            self._vaos[id(prog)] = vao
        return prog, vao

    def __len__(self) -> int:
        return len(self._programs)

    def release(self) -> None:
        for vao in self._vaos.values():
            vao.release()
        for prog in self._programs.values():
            prog.release()
        self._vaos.clear()
        self._programs.clear()

    # -- source assembly ---------------------------------------------------------------------
    def source(self, name: str, stage: str, defines=()) -> tuple[str, list]:
        """The full source of one stage and the file table (index = GLSL source-string number)."""
        files: list[str] = []
        body = self._expand(self._path(name), files, set())
        head = [COMPUTE_VERSION if stage == COMPUTE else GLSL_VERSION, f"#define {stage}"]
        head += [f"#define {k} {v}".rstrip() for k, v in defines]
        return "\n".join(head) + "\n" + body, files

    def _path(self, rel: str) -> Path:
        p = self.shader_dir / (rel if rel.endswith(".glsl") else rel + ".glsl")
        return p

    def _expand(self, path: Path, files: list, seen: set, includer: str | None = None) -> str:
        rel = path.relative_to(self.shader_dir).as_posix() if path.is_relative_to(self.shader_dir) else str(path)
        if not path.is_file():
            where = f" (included from {includer})" if includer else ""
            raise ShaderError(f"shader file '{rel}' not found in {self.shader_dir}{where}")
        seen.add(path.resolve())
        idx = len(files)
        files.append(rel)
        base = idx * _LINE_STRIDE  # file k's lines are numbered k * stride + n (robust to drivers
        out = [f"#line {base + 1} {idx}"]  # that misreport the source-string number)
        included = False
        for lineno, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
            m = _INCLUDE.match(line)
            if not m:
                out.append(line)
                if included and _BRANCH.match(line):  # a #line in a skipped group is ignored:
                    out.append(f"#line {base + lineno + 1} {idx}")  # number again past it
                continue
            included = True
            inc = (self.shader_dir / m.group(1))
            if inc.resolve() in seen:
                out.append(f"// {m.group(1)} already included")
                continue
            out.append(self._expand(inc, files, seen, f"{rel}:{lineno}"))
            out.append(f"#line {base + lineno + 1} {idx}")
        return "\n".join(out)

    # -- compile -----------------------------------------------------------------------------
    def _build(self, name: str, defines: tuple, varyings) -> moderngl.Program:
        path = self._path(name)
        if not path.is_file():
            raise ShaderError(f"shader '{name}' not found: {path} does not exist")
        text = path.read_text(encoding="utf-8")
        stages = {}
        files = []
        for stage in program_stages(text, defines):
            stages[stage], files = self.source(name, stage, defines)
        if "VERTEX_SHADER" not in stages:
            raise ShaderError(f"shader '{name}' has no VERTEX_SHADER section")
        kwargs = dict(vertex_shader=stages["VERTEX_SHADER"],
                      geometry_shader=stages.get("GEOMETRY_SHADER"),
                      fragment_shader=stages.get("FRAGMENT_SHADER"))
        if varyings:
            kwargs["varyings"] = list(varyings)
        if self.shader_dir.resolve() == default_shader_dir().resolve():
            _record(name, defines, varyings)
        try:
            return self.ctx.program(**kwargs)
        except Exception as exc:
            log = _map_log(str(exc), files)
            dtxt = ", ".join(f"{k}={v}" if v else k for k, v in defines) or "none"
            raise ShaderError(f"shader '{name}' failed to build (defines: {dtxt}):\n{log}") from None

    def _build_compute(self, name: str, defines: tuple) -> moderngl.ComputeShader:
        path = self._path(name)
        if not path.is_file():
            raise ShaderError(f"shader '{name}' not found: {path} does not exist")
        if COMPUTE not in path.read_text(encoding="utf-8"):
            raise ShaderError(f"shader '{name}' has no COMPUTE_SHADER section")
        if self.ctx.version_code < COMPUTE_GL:
            raise ShaderError(f"shader '{name}' is a compute program: it needs OpenGL 4.3, this context "
                              f"offers {self.ctx.version_code // 100}.{self.ctx.version_code % 100 // 10}")
        source, files = self.source(name, COMPUTE, defines)
        if self.shader_dir.resolve() == default_shader_dir().resolve():
            _record(name, defines, None, COMPUTE)
        try:
            return self.ctx.compute_shader(source)
        except Exception as exc:
            log = _map_log(str(exc), files)
            dtxt = ", ".join(f"{k}={v}" if v else k for k, v in defines) or "none"
            raise ShaderError(f"shader '{name}' failed to build as a compute program "
                              f"(defines: {dtxt}):\n{log}") from None


def _define_value(v) -> str:
    if isinstance(v, bool):
        return "1" if v else "0"
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v) if ("." in repr(v) or "e" in repr(v)) else repr(v) + ".0"
    return str(v)


_LOG_PATTERNS = (
    re.compile(r"\b(\d+):(\d+)\((\d+)\)"),  # Mesa:   0:12(3): error
    re.compile(r"\b(\d+):(\d+):"),  # AMD/Apple: ERROR: 0:12: ...
    re.compile(r"\b(\d+)\((\d+)\)\s*:"),  # NVIDIA: 0(12) : error
)


def _map_log(log: str, files: list) -> str:
    """Replace GLSL locations by file names: ``1:100012(3)`` -> ``common/x.glsl:12(3)``."""
    def loc(src, line):
        line = int(line)
        k, n = divmod(line, _LINE_STRIDE)
        if not (0 <= k < len(files)):
            k = int(src)
        return f"{files[k] if 0 <= k < len(files) else src}:{n}"

    lines = []
    for line in log.splitlines():
        m = _LOG_PATTERNS[0].search(line)
        if m:
            line = line[:m.start()] + f"{loc(m.group(1), m.group(2))}({m.group(3)})" + line[m.end():]
        else:
            for pat in _LOG_PATTERNS[1:]:
                m = pat.search(line)
                if m:
                    line = line[:m.start()] + f"{loc(m.group(1), m.group(2))}:" + line[m.end():]
                    break
        lines.append(line)
    return "\n".join(lines)
