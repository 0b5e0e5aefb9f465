"""tools/shader_check.py: it finds programs and their defines, reports a broken shader with its
program, stage, define set and file:line, and rejects what strict GLSL 4.10 rejects."""
import json
import os
from pathlib import Path

import pytest

from hybrid_shadow_addon.core.gpu import programs
from hybrid_shadow_addon.core.gpu.programs import ProgramCache
from tools import shader_check

needs_glslang = pytest.mark.skipif(shader_check.find_validator() is None,
                                   reason="glslangValidator not installed (glslang-tools)")

FULLSCREEN = """out vec2 v_uv;
void main() {
    vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
    v_uv = p;
    gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}
"""

# a program whose include is broken only under HS_BROKEN (an undeclared name on line 3)
GOOD_PROGRAM = """// test program
#ifdef VERTEX_SHADER
#include "common/fullscreen.glsl"
#endif
#ifdef FRAGMENT_SHADER
#include "common/shade.glsl"
out vec4 o_color;
void main() { o_color = vec4(shade(), 1.0); }
#endif
"""
SHADE = """#ifndef HS_SHADE_GLSL
#define HS_SHADE_GLSL
vec3 shade() {
#ifdef HS_BROKEN
    return vec3(undeclared_name);
#elif HS_LEVEL > 1
    return vec3(0.5);
#else
    return vec3(1.0);
#endif
}
#endif
"""


def _shaders(tmp_path, files: dict) -> Path:
    root = tmp_path / "shaders"
    for rel, text in {"common/fullscreen.glsl": FULLSCREEN, **files}.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    return root


def test_discovery_finds_programs_and_their_defines(tmp_path):
    root = _shaders(tmp_path, {"good.glsl": GOOD_PROGRAM, "common/shade.glsl": SHADE})
    assert shader_check.program_names(root) == ["good"]
    cache = ProgramCache(None, root)
    flags, values = shader_check.optional_defines(cache, "good")
    assert flags == {"HS_BROKEN": 1}  # HS_SHADE_GLSL is the include's own guard
    assert values == {"HS_LEVEL": [2]}
    sets = shader_check.single_define_sets(cache, "good")
    assert {} in sets and {"HS_BROKEN": 1} in sets and {"HS_LEVEL": 2} in sets


def test_the_real_programs_are_found():
    names = shader_check.program_names(programs.default_shader_dir())
    assert {"raytrace", "lighting", "gbuffer"} <= set(names)
    assert not any(n.startswith("common/") for n in names)


# a compute program, broken only under HS_BROKEN, that reads a kernel define as raytrace.glsl does
COMPUTE_PROGRAM = """// test compute program
#ifdef COMPUTE_SHADER
layout(local_size_x = 8) in;
layout(std430, binding = 0) buffer out_buf { uint v[]; };
void main() {
#ifdef HS_QUEUE_GEN
    v[gl_GlobalInvocationID.x] = 1u;
#else
    v[gl_GlobalInvocationID.x] = 2u;
#endif
#ifdef HS_BROKEN
    v[0] = undeclared_name;
#endif
}
#endif
"""


def test_compute_programs_are_checked(tmp_path, gl_ctx):
    """A file with a COMPUTE_SHADER section is a compute program: found, each set with one of
    the queue's kernels, compiled at #version 430 with the GL and glslang; its failure names
    the compute stage."""
    root = _shaders(tmp_path, {"kernel.glsl": COMPUTE_PROGRAM})
    assert shader_check.programs(root) == [("kernel", "compute")]
    sets = shader_check.single_define_sets(ProgramCache(None, root), "kernel", "compute")
    assert all(("HS_QUEUE_TRACE" in d) != ("HS_QUEUE_GEN" in d) for d in sets)
    assert {"HS_QUEUE_GEN": 1} in sets and {"HS_BROKEN": 1, "HS_QUEUE_TRACE": 1} in sets
    failures, text = _failures(root, glslang=shader_check.find_validator() is not None)
    assert failures and all(f.stage == programs.COMPUTE and "HS_BROKEN" in f.defines for f in failures)
    assert "kernel.glsl:12" in text


def test_raytrace_is_checked_as_both_stages():
    cache = ProgramCache(None, programs.default_shader_dir())
    assert {("raytrace", "graphics"), ("raytrace", "compute"), ("queue_marked", "compute")} <= set(
        shader_check.programs(programs.default_shader_dir()))
    graphics = shader_check.single_define_sets(cache, "raytrace", "graphics")
    compute = shader_check.single_define_sets(cache, "raytrace", "compute")
    kernels = set(shader_check.COMPUTE_KERNELS)
    assert not any(kernels & set(d) for d in graphics)
    assert all(len(kernels & set(d)) == 1 for d in compute)
    assert not any(set(shader_check.COMPUTE_ONLY) & set(d) for d in graphics)
    assert any("HS_QUEUE_LANES" in d and "HS_QUEUE_TRACE" in d for d in compute)


def test_companions_follow_requirements():
    sets = shader_check.with_companions({}, "HS_PACKET_PLANES", 1)
    assert {"HS_SOFT_PACKET", "HS_SOFT", "HS_STRUCTURE_BVH"} <= set(sets)
    assert shader_check.with_companions({}, "HS_SOFT_SHAPE", 2)["HS_LIGHT_LOCAL"] == 1
    assert "HS_LIGHT_LOCAL" not in shader_check.with_companions({}, "HS_SOFT_SHAPE", 0)


def test_each_set_names_one_structure():
    """A program that reads the scene is tried under exactly one acceleration structure: the
    default where the define under test is not one, else the one under test."""
    cache = ProgramCache(None, programs.default_shader_dir())
    sets = shader_check.single_define_sets(cache, "raytrace")
    group = set(shader_check.ONE_OF[0])
    assert all(len(group & set(s)) == 1 for s in sets)
    assert any("HS_STRUCTURE_GRID" in s for s in sets) and any("HS_STRUCTURE_BVH" in s for s in sets)


def _failures(root, **kwargs):
    lines = []
    failures = shader_check.run_check(root, out=lines.append, **kwargs)
    return failures, "\n".join(lines)


def test_gl_reports_a_broken_shader_with_file_and_line(tmp_path, gl_ctx):
    root = _shaders(tmp_path, {"good.glsl": GOOD_PROGRAM, "common/shade.glsl": SHADE})
    failures, text = _failures(root, glslang=False)
    assert len(failures) == 1, text
    bad = failures[0]
    assert (bad.compiler, bad.program, bad.stage, bad.defines) == ("gl", "good", "FRAGMENT_SHADER", {"HS_BROKEN": 1})
    assert "common/shade.glsl:5" in bad.log
    assert "FAIL [gl] good FRAGMENT_SHADER (defines: HS_BROKEN=1)" in text
    assert "no recording" in text


@needs_glslang
def test_glslang_reports_a_broken_shader_with_file_and_line(tmp_path):
    root = _shaders(tmp_path, {"good.glsl": GOOD_PROGRAM, "common/shade.glsl": SHADE})
    failures, text = _failures(root, gl=False)
    assert [(f.compiler, f.stage, f.defines) for f in failures] == [("glslang", "FRAGMENT_SHADER", {"HS_BROKEN": 1})]
    assert "common/shade.glsl:5:" in failures[0].log, text


@needs_glslang
def test_glslang_rejects_what_410_core_lacks(tmp_path):
    """An explicit sampler binding is GLSL 4.20 (or ARB_shading_language_420pack); a macro's line
    continuation also: Mesa takes both under #version 410 core, the check does not."""
    binding = GOOD_PROGRAM.replace('#include "common/shade.glsl"', "layout(binding = 0) uniform sampler2D u_tex;")
    binding = binding.replace("shade()", "texture(u_tex, vec2(0.5)).rgb")
    continued = GOOD_PROGRAM.replace('#include "common/shade.glsl"', "#define HS_ONE \\\n    vec3(1.0)")
    continued = continued.replace("shade()", "HS_ONE")
    root = _shaders(tmp_path, {"binding.glsl": binding, "continued.glsl": continued})
    failures, text = _failures(root, gl=False)
    assert {(f.program, f.stage) for f in failures} == {  # a line continuation fails in skipped code too
        ("binding", "FRAGMENT_SHADER"), ("continued", "VERTEX_SHADER"), ("continued", "FRAGMENT_SHADER")}, text
    by_name = {f.program: f.log for f in failures}
    assert "binding.glsl:6:" in by_name["binding"] and "binding" in by_name["binding"]
    assert "continued.glsl:6:" in by_name["continued"] and "line continuation" in by_name["continued"]


def test_recorded_sets_are_checked(tmp_path, gl_ctx):
    root = _shaders(tmp_path, {"good.glsl": GOOD_PROGRAM, "common/shade.glsl": SHADE})
    rec = tmp_path / "rec.jsonl"
    rows = [{"program": "good", "defines": {"HS_LEVEL": "7"}, "varyings": []}] * 2
    rec.write_text("".join(json.dumps(r) + "\n" for r in rows))
    assert shader_check.recorded_sets(rec) == {("good", "graphics"): [{"HS_LEVEL": "7"}]}
    failures, text = _failures(root, recorded=rec, glslang=False)
    assert "1 recorded define sets" in text
    assert len(failures) == 1  # HS_BROKEN alone; the recorded set compiles


def test_programs_record_their_define_sets(tmp_path, gl_ctx, monkeypatch):
    rec = tmp_path / "rec.jsonl"
    monkeypatch.setenv("HS_RECORD_DEFINES", str(rec))
    monkeypatch.setattr(programs, "_recorded", set())
    cache = ProgramCache(gl_ctx)
    cache.get("upsample")
    cache.get("upsample")
    ProgramCache(gl_ctx).get("upsample")
    rows = [json.loads(line) for line in rec.read_text().splitlines()]
    assert rows == [{"program": "upsample", "defines": {}, "varyings": []}]
    # programs outside shaders/ (the tests' own) are not recorded
    other = _shaders(tmp_path, {"good.glsl": GOOD_PROGRAM, "common/shade.glsl": SHADE})
    ProgramCache(gl_ctx, other).get("good")
    assert len(rec.read_text().splitlines()) == 1


def test_the_check_leaves_the_recording_on(tmp_path, monkeypatch):
    """Tests that run after this module still record (make test's HS_RECORD_DEFINES)."""
    monkeypatch.setenv("HS_RECORD_DEFINES", str(tmp_path / "rec.jsonl"))
    root = _shaders(tmp_path, {"good.glsl": GOOD_PROGRAM, "common/shade.glsl": SHADE})
    _failures(root, gl=False, glslang=False)
    assert os.environ["HS_RECORD_DEFINES"] == str(tmp_path / "rec.jsonl")


@needs_glslang
def test_the_command_fails_on_a_broken_shader(tmp_path, capsys):
    broken = _shaders(tmp_path / "broken", {"good.glsl": GOOD_PROGRAM, "common/shade.glsl": SHADE})
    assert shader_check.main(["--shader-dir", str(broken), "--no-gl"]) == 1
    assert "common/shade.glsl:5:" in capsys.readouterr().out
    fixed = _shaders(tmp_path / "fixed", {"good.glsl": GOOD_PROGRAM,
                                          "common/shade.glsl": SHADE.replace("undeclared_name", "0.25")})
    assert shader_check.main(["--shader-dir", str(fixed), "--no-gl"]) == 0


def test_the_reprojection_is_checked_in_each_mode(tmp_path, gl_ctx):
    """reproject.glsl is one of the run's programs, tried in each of its modes (STORE, SOFT,
    HISTORY and the hard mark, moving or still), and a break in one mode fails the run there."""
    import shutil

    assert "reproject" in shader_check.program_names(programs.default_shader_dir())
    sets = shader_check.single_define_sets(ProgramCache(None, programs.default_shader_dir()), "reproject")
    for mode in ("STORE", "SOFT", "HISTORY", "HS_STILL", "HS_BOXES"):
        assert any(mode in s for s in sets), mode
    assert any(not {"STORE", "SOFT", "HISTORY"} & set(s) for s in sets)
    root = tmp_path / "shaders"
    shutil.copytree(programs.default_shader_dir(), root)
    src = root / "reproject.glsl"
    text = src.read_text()
    cache = ProgramCache(gl_ctx, root)
    assert not [f for s in sets for f in shader_check.check_gl(cache, "reproject", s)]
    broken = "{ o_sums = vec4(0.0); return; }"
    assert broken in text
    src.write_text(text.replace(broken, "{ o_sums = vec4(0.0) + hs_undefined; return; }"))
    cache = ProgramCache(gl_ctx, root)
    failed = [f for s in sets for f in shader_check.check_gl(cache, "reproject", s)]
    assert failed and all("SOFT" in f.defines for f in failed)
