"""Compiles every GLSL program in ``shaders/`` under its define sets, with the running GL and with
the Khronos reference compiler (``glslangValidator``) against strict ``#version 410 core``.

The define sets are (a) those the test suite built, recorded with ``HS_RECORD_DEFINES`` (see
``hybrid_shadow_addon/core/gpu/programs.py``; ``make test`` records and then runs this with
``--recorded``), and (b) each optional define of a program on its own: every name a program's
sources test with ``#ifdef`` / ``#ifndef`` / ``#if`` that the sources do not ``#define``
themselves, and each value a ``#if`` compares a numeric define with. Programs are the files of
``shaders/`` that have a ``VERTEX_SHADER`` section (graphics) or a ``COMPUTE_SHADER`` section
(compute, ``#version 430 core``, with the GL when it offers 4.3) and that no other file
includes; a file with both is checked as each. Sources are assembled by :class:`ProgramCache`
exactly as the add-on does. A failure names the program, the
stage, the define set and ``file:line``; the exit status is 1 when any compile fails.

    .venv/bin/python -m tools.shader_check [--recorded out/test/shader_defines.jsonl]
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from hybrid_shadow_addon.core.gpu import programs as _programs

REPO = Path(__file__).resolve().parents[1]

#: Numeric defines the shaders use as numbers (array sizes, shifts, loop bounds): the code always
#: gives one to a program that reads it, so every define set lacking it gets this value, the one
#: of the default bake (BakedScene.defines: 4096-texel rows, 2^14 rows, a 3-level grid, 4-triangle
#: leaves) and of the passes (light_cull.py's 8-pixel block; a lighting batch of 1 mask, a point
#: light's (an area light's mask needs the HS_LIT_AREA_* code); lighting.py's uniform block of 5 rows).
VALUES = {
    "HS_TEX_WIDTH": 4096, "HS_TEX_WIDTH_LOG2": 12, "HS_TEX_ROWS_LOG2": 14, "HS_GRID_LEVELS": 3,
    "HS_BVH_LEAF_SIZE": 4, "HS_CULL_BLOCK": 8, "HS_MASKS": 1, "HS_MASKS_POINT": 1, "HS_LIGHT_ROWS": 5,
    "HS_SOFT_SHAPE": 0, "HS_WIDE_STACK": 32,
}

#: Defines that the code only ever gives together with others (a key ``NAME=value`` applies to
#: that value alone): the check adds these companions, recursively, when it tries the key on its
#: own. A soft light's sub-passes are variants of raytrace.py's soft program, which always carries
#: HS_SOFT; packets walk the two-level BVH only (raytrace.py's _soft_defines); soft shapes 1 and 2
#: (sphere, area) are local lights, shape 0 the sun (soft_light.glsl); 4-wide nodes are a layout of
#: the two-level BVH (its bake's defines); a bake has alpha-cut
#: casters only where some mesh caster has triangles (AccelerationStructure.has_alpha).
REQUIRES = {
    "HS_HAS_ALPHA": ("HS_HAS_MESHES",),
    "HS_SOFT_SHAPE": ("HS_SOFT",),
    "HS_SOFT_SHAPE=1": ("HS_SOFT", "HS_LIGHT_LOCAL"),
    "HS_SOFT_SHAPE=2": ("HS_SOFT", "HS_LIGHT_LOCAL"),
    "HS_SOFT_PROBE": ("HS_SOFT",),
    "HS_QUEUE_LANES": ("HS_SOFT_ACCUM",),
    "HS_SOFT_REFINE": ("HS_SOFT",),
    "HS_SOFT_ACCUM": ("HS_SOFT",),
    "HS_SOFT_FULL": ("HS_SOFT",),
    "HS_SOFT_PACKET": ("HS_SOFT", "HS_STRUCTURE_BVH"),
    "HS_PACKET_PLANES": ("HS_SOFT_PACKET",),
    "HS_BVH_WIDE": ("HS_STRUCTURE_BVH",),
    "HS_WIDE_STACK": ("HS_BVH_WIDE",),
}

#: Defines of which the code always gives exactly one (the first: when the program tests the group
#: but the set under test names none): a program that reads the scene is compiled for one
#: acceleration structure (BakedScene.defines; scene_data.glsl stops with #error without one).
ONE_OF = (("HS_STRUCTURE_BVH", "HS_STRUCTURE_GRID"),)

#: Mode defines: a program that tests one is built only in one of its modes (soft_accumulate.glsl
#: has a ``main`` per mode), so its set without any of them is not compiled.
MODES = ("RESOLVE", "PARTIAL", "NOISE", "ACCUMULATE", "DENOISE")

#: Defines whose sets are compiled with the running GL only, with the reason. HS_GROUP_VOTE uses
#: GL_ARB_shader_group_vote, which glslang declares only from ``#version 430``; refine.py asks
#: for it only where the running GL offers the extension, so the GL compile is the one that counts.
GL_ONLY = {"HS_GROUP_VOTE": "glslang declares GL_ARB_shader_group_vote from #version 430 only"}

#: The compute stage's kernels (``shaders/common/ray_queue.glsl``): a compute set of a program
#: that tests them names one (the first where it names none); a graphics set names none.
COMPUTE_KERNELS = ("HS_QUEUE_TRACE", "HS_QUEUE_GEN")
#: Defines of the compute stage's tracing kernel alone (``#error`` elsewhere: raytrace.glsl's
#: lanes of a queued texel): a graphics set with one is not compiled.
COMPUTE_ONLY = ("HS_QUEUE_LANES",)
#: Lines of a compiler's log kept per failure.
LOG_LINES = 12

_STAGE_SUFFIX = {"VERTEX_SHADER": "vert", "GEOMETRY_SHADER": "geom", "FRAGMENT_SHADER": "frag",
                 _programs.COMPUTE: "comp"}
_GL_STAGE = {"vertex_shader": "VERTEX_SHADER", "geometry_shader": "GEOMETRY_SHADER",
             "fragment_shader": "FRAGMENT_SHADER"}
_DIRECTIVE = re.compile(r"^\s*#\s*(ifdef|ifndef|if|elif|define)\b(.*)$")
_NAME = re.compile(r"\b[A-Za-z_]\w*\b")
_COMPARE = re.compile(r"\b([A-Z_][A-Z0-9_]*)\s*(==|!=|>=|<=|>|<)\s*(\d+)")
_DEFINED = re.compile(r"\bdefined\s*\(?\s*([A-Za-z_]\w*)")


@dataclass
class Failure:
    """One compile that failed: which compiler, program, stage, define set, and the mapped log."""
    compiler: str
    program: str
    stage: str
    defines: dict
    log: str

    def __str__(self) -> str:
        dtxt = ", ".join(f"{k}={v}" if v != "" else k for k, v in sorted(self.defines.items())) or "none"
        lines = self.log.strip().splitlines()
        more = [f"... ({len(lines) - LOG_LINES} more lines)"] if len(lines) > LOG_LINES else []
        body = "\n".join("    " + line for line in lines[:LOG_LINES] + more)
        return f"FAIL [{self.compiler}] {self.program} {self.stage} (defines: {dtxt})\n{body}"


# -- discovery ----------------------------------------------------------------------------------
def program_names(shader_dir: Path) -> list[str]:
    """The programs: files with a ``VERTEX_SHADER`` or ``COMPUTE_SHADER`` section that no file
    ``#include``s."""
    return list(dict.fromkeys(name for name, _ in programs(shader_dir)))


def programs(shader_dir: Path) -> list[tuple[str, str]]:
    """``(name, kind)`` of each program, ``kind`` ``graphics`` or ``compute`` (a file with both
    sections is both)."""
    files = sorted(shader_dir.rglob("*.glsl"))
    included = set()
    for path in files:
        for line in path.read_text(encoding="utf-8").splitlines():
            m = _programs._INCLUDE.match(line)
            if m:
                included.add((shader_dir / m.group(1)).resolve())
    out = []
    for p in files:
        if p.resolve() in included:
            continue
        text = p.read_text(encoding="utf-8")
        name = p.relative_to(shader_dir).with_suffix("").as_posix()
        for kind, marker in (("graphics", "VERTEX_SHADER"), ("compute", _programs.COMPUTE)):
            if marker in text:
                out.append((name, kind))
    return out


def program_files(cache: _programs.ProgramCache, name: str) -> list[Path]:
    """The files a program's source is assembled from (the program first, then its includes)."""
    _, files = cache.source(name, "VERTEX_SHADER")
    return [cache.shader_dir / rel for rel in files]


def optional_defines(cache: _programs.ProgramCache, name: str) -> tuple[dict, dict]:
    """``(flags, values)`` of a program: the names its sources test but do not ``#define``
    (flags, given as ``1``) and, per numeric define a ``#if`` compares, the values that decide
    a branch (``== n``: n; ``> n``: n + 1; ...)."""
    tested: set = set()
    defined: set = set()
    compared: dict = {}
    for path in program_files(cache, name):
        for line in path.read_text(encoding="utf-8").splitlines():
            m = _DIRECTIVE.match(line)
            if not m:
                continue
            kind, rest = m.group(1), m.group(2).split("//")[0]
            if kind == "define":
                names = _NAME.findall(rest)
                if names:
                    defined.add(names[0])
                continue
            tested.update(n for n in _NAME.findall(rest) if n != "defined" and not n.isdigit())
            for var, op, num in _COMPARE.findall(rest):
                num = int(num)
                compared.setdefault(var, set()).update(
                    {"==": {num}, "!=": {num}, ">=": {num}, "<=": {num}, ">": {num + 1}, "<": {num - 1}}[op])
    tested -= set(_programs.STAGES) | {_programs.COMPUTE} | defined
    flags = {n: 1 for n in sorted(tested - set(compared))}
    values = {n: sorted(v) for n, v in sorted(compared.items()) if n in tested}
    return flags, values


def mentioned_values(cache: _programs.ProgramCache, name: str) -> dict:
    """The :data:`VALUES` a program's sources mention, outside ``#ifdef`` tests of them."""
    text = "\n".join(p.read_text(encoding="utf-8") for p in program_files(cache, name))
    optional = set(re.findall(r"#\s*ifn?def\s+(\w+)", text)) | set(_DEFINED.findall(text))
    return {k: v for k, v in VALUES.items() if re.search(rf"\b{k}\b", text) and k not in optional}


def with_companions(base: dict, key: str, value) -> dict:
    """``base`` with ``key`` set to ``value`` and the companions :data:`REQUIRES` names for it
    (and for them); ``key`` replaces the other members of its :data:`ONE_OF` group."""
    out = {**base, key: value}
    for group in ONE_OF:
        if key in group:
            for other in group:
                if other != key:
                    out.pop(other, None)
    todo = [(key, value)]
    while todo:
        name, val = todo.pop()
        for extra in REQUIRES.get(f"{name}={val}", REQUIRES.get(name, ())):
            if extra not in out:
                out[extra] = VALUES.get(extra, 1)
                todo.append((extra, out[extra]))
    return out


def single_define_sets(cache: _programs.ProgramCache, name: str, kind: str = "graphics") -> list[dict]:
    """(b): the base set, then each optional define on its own, then each decisive value (a
    ``compute`` program's sets each with one of :data:`COMPUTE_KERNELS`; a graphics
    program's without the kernels and :data:`COMPUTE_ONLY`)."""
    base = mentioned_values(cache, name)
    flags, values = optional_defines(cache, name)
    kernels = [k for k in COMPUTE_KERNELS if k in flags]
    for k in COMPUTE_KERNELS:
        flags.pop(k, None)
    if kind != "compute":
        for k in COMPUTE_ONLY:
            flags.pop(k, None)
    for group in ONE_OF:
        if set(group) & set(flags):
            base[group[0]] = 1
    sets = [] if set(flags) & set(MODES) else [dict(base)]
    for flag in flags:
        sets.append(with_companions(base, flag, VALUES.get(flag, 1)))
    for var, nums in values.items():
        for num in nums:
            sets.append(with_companions(base, var, num))
    if kind == "compute" and kernels:
        first, *rest = COMPUTE_KERNELS
        sets = [{**d, first: 1} for d in sets] + [{**base, k: 1} for k in rest]
    return _unique(sets)


def recorded_sets(path: Path) -> dict:
    """(a): ``{(program, kind): [defines, ...]}`` from a recording, duplicates dropped."""
    out: dict = {}
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.strip():
            rec = json.loads(line)
            kind = "compute" if rec.get("stage") == _programs.COMPUTE else "graphics"
            out.setdefault((rec["program"], kind), []).append(rec["defines"])
    return {k: _unique(v) for k, v in out.items()}


def _unique(sets: list) -> list:
    seen, out = set(), []
    for d in sets:
        key = tuple(sorted((k, str(v)) for k, v in d.items()))
        if key not in seen:
            seen.add(key)
            out.append(d)
    return out


# -- compilers ----------------------------------------------------------------------------------
def _frozen(defines: dict) -> tuple:
    return tuple(sorted((str(k), _programs._define_value(v)) for k, v in defines.items()))


def check_gl(cache: _programs.ProgramCache, name: str, defines: dict, kind: str = "graphics") -> list[Failure]:
    """Build the program with the running GL (moderngl) exactly as the add-on does."""
    try:
        if kind == "compute":
            prog = cache._build_compute(name, _frozen(defines))
        else:
            prog = cache._build(name, _frozen(defines), None)
    except _programs.ShaderError as exc:
        text = str(exc).split("\n", 1)[-1]
        stage = _programs.COMPUTE if kind == "compute" else next(
            (s for k, s in _GL_STAGE.items() if k in text), "link")
        return [Failure("gl", name, stage, defines, text)]
    prog.release()
    return []


def check_glslang(cache: _programs.ProgramCache, name: str, defines: dict, validator: str,
                  workdir: Path, kind: str = "graphics") -> list[Failure]:
    """Compile each stage with glslangValidator (``#version 410 core``, compute ``#version 430
    core``, no extensions assumed)."""
    text = cache._path(name).read_text(encoding="utf-8")
    failures = []
    stages = [_programs.COMPUTE] if kind == "compute" else _programs.program_stages(text, _frozen(defines))
    for stage in stages:
        source, files = cache.source(name, stage, _frozen(defines))
        path = workdir / f"{name.replace('/', '_')}.{_STAGE_SUFFIX[stage]}"
        path.write_text(source, encoding="utf-8")
        run = subprocess.run([validator, str(path)], capture_output=True, text=True)
        if run.returncode != 0:
            log = "\n".join(line for line in (run.stdout + run.stderr).splitlines()
                            if line.strip() and line.strip() != str(path))
            failures.append(Failure("glslang", name, stage, defines, _programs._map_log(log, files)))
    return failures


def find_validator() -> str | None:
    """``glslangValidator`` on PATH (Debian: ``glslang-tools``), else None."""
    return shutil.which("glslangValidator")


def run_check(shader_dir: Path | None = None, recorded: Path | None = None, gl: bool = True,
              glslang: bool = True, out=print) -> list[Failure]:
    """Every program under (a) its recorded sets and (b) its single-define sets; the failures."""
    ctx = None
    if gl:
        from hybrid_shadow_addon.core.gpu.context import create_context
        ctx = create_context()
    cache = _programs.ProgramCache(ctx, shader_dir)
    validator = find_validator() if glslang else None
    if glslang and validator is None:
        raise SystemExit("shader check: glslangValidator not found (sudo apt-get install glslang-tools)")
    progs = programs(cache.shader_dir)
    gl_compute = ctx is not None and ctx.version_code >= _programs.COMPUTE_GL
    if gl and not gl_compute and any(kind == "compute" for _, kind in progs):
        out("shader check: this GL offers no compute shaders: compute programs with glslang only")
    sets = {p: single_define_sets(cache, *p) for p in progs}
    n_recorded = 0
    if recorded is not None and recorded.is_file():
        for p, rec in recorded_sets(recorded).items():
            if p in sets:
                sets[p] = _unique(rec + sets[p])
                n_recorded += len(rec)
        out(f"shader check: {n_recorded} recorded define sets from {recorded}")
    else:
        where = f" ({recorded} not found)" if recorded is not None else ""
        out(f"shader check: no recording{where}: each optional define on its own only")
    failures: list[Failure] = []
    compilers = [c for c, on in (("gl", gl), ("glslang", glslang)) if on]
    with tempfile.TemporaryDirectory(prefix="hs-shader-check-") as tmp:
        for (n, kind), each in sets.items():
            for defines in each:
                if gl and (kind == "graphics" or gl_compute):
                    failures += check_gl(cache, n, defines, kind)
                if glslang and not set(defines) & set(GL_ONLY):
                    failures += check_glslang(cache, n, defines, validator, Path(tmp), kind)
    total = sum(len(v) for v in sets.values())
    for f in failures:
        out(str(f))
    out(f"shader check: {len(sets)} programs, {total} define sets, {'+'.join(compilers)}: "
        f"{len(failures)} failed")
    if ctx is not None:
        cache.release()
        ctx.release()
    return failures


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--recorded", type=Path, help="the HS_RECORD_DEFINES file of a test run")
    ap.add_argument("--shader-dir", type=Path, help="default: the add-on's shaders/")
    ap.add_argument("--no-gl", action="store_true", help="skip the running GL")
    ap.add_argument("--no-glslang", action="store_true", help="skip glslangValidator")
    args = ap.parse_args(argv)
    os.environ.pop("HS_RECORD_DEFINES", None)  # the check's own builds are not part of a recording
    failures = run_check(args.shader_dir, args.recorded, gl=not args.no_gl, glslang=not args.no_glslang)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
