#!/usr/bin/env bash
# Sets up everything `make demo` and `make test` need, on a fresh Debian/Ubuntu machine:
# python3.11, the Mesa EGL libraries, glslang-tools (the shader check's reference compiler),
# Node.js (a test of the Flamenco job type), a .venv with the pinned requirements (bpy 4.5 LTS,
# ruff) and, where python3.13 is found, .venv-bpy5 (bpy 5.x); the add-on package is installed
# editable into each (`pip install -e .`), so that the tools and benchmarks import it wherever they run.
# A second run only checks (a few hundred milliseconds): nothing is reinstalled.
set -euo pipefail
cd "$(dirname "$0")/.."

die() { echo "setup: $*" >&2; exit 1; }
as_root() { [ "$(id -u)" = 0 ]; }
apt_install() {
    if as_root && command -v apt-get >/dev/null; then
        echo "setup: installing $* with apt-get"
        export DEBIAN_FRONTEND=noninteractive
        apt-get update -qq >/dev/null && apt-get install -y -qq "$@" >/dev/null
    else
        die "missing system packages; run: sudo apt-get install -y $*"
    fi
}

# 1. python3.11 (bpy from PyPI is built for CPython 3.11 only)
PY=""
for cand in "${PYTHON311:-}" python3.11 python3; do
    [ -n "$cand" ] || continue
    if command -v "$cand" >/dev/null && "$cand" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 11))' 2>/dev/null; then
        PY=$(command -v "$cand"); break
    fi
done
if [ -z "$PY" ]; then
    if as_root && command -v apt-get >/dev/null && apt-cache show python3.11 >/dev/null 2>&1; then
        apt_install python3.11 python3.11-venv
        PY=$(command -v python3.11)
    else
        die "python3.11 not found (bpy is cp311-only). Install it: 'sudo apt-get install python3.11 python3.11-venv' (Debian 12 / Ubuntu 22.04+), or 'pyenv install 3.11', or set PYTHON311=/path/to/python3.11."
    fi
fi

# 2. Mesa EGL (moderngl's headless context; bpy aborts without it)
missing=()
ldconfig -p 2>/dev/null | grep -q 'libEGL.so.1 ' || missing+=(libegl1)
ldconfig -p 2>/dev/null | grep -q 'libGL.so.1 ' || missing+=(libgl1)
compgen -G '/usr/lib/*/dri/swrast_dri.so' >/dev/null || compgen -G '/usr/lib*/dri/swrast_dri.so' >/dev/null || missing+=(libgl1-mesa-dri)
if [ ${#missing[@]} -gt 0 ]; then
    apt_install libegl1 libgl1-mesa-dri libgl1
fi

# 2b. glslangValidator: tools/shader_check.py compiles the shaders against strict GLSL 4.10 with it
command -v glslangValidator >/dev/null || apt_install glslang-tools

# 3. Node.js (tests/test_flamenco.py evaluates the Flamenco job type with it; optional: without
#    it and without root, that test is skipped)
if ! command -v node >/dev/null && ! command -v nodejs >/dev/null; then
    if as_root && command -v apt-get >/dev/null; then
        apt_install nodejs
    else
        echo "setup: Node.js not found (tests/test_flamenco.py will be skipped); run: sudo apt-get install -y nodejs" >&2
    fi
fi

# 4. the virtual environments with the pinned requirements: .venv (bpy 4.5 LTS, CPython 3.11)
#    and .venv-bpy5 (bpy 5.x, CPython 3.13: a second run of the export, pipeline and add-on tests),
#    each with the project installed editable (its setuptools pinned with the requirements: the
#    build runs without isolation, so nothing else is fetched). The stamp covers both the
#    requirements and pyproject.toml; a missing install (its .dist-info) is found without Python.
quiet() { "$@" 2> >(grep -v 'is ignored: it is neither a file nor a directory' >&2); }  # (local mirror noise)
make_venv() {  # make_venv DIR PYTHON REQUIREMENTS
    local dir=$1 py=$2 reqs=$3 stamp="$1/.requirements.sha256" want
    want=$(cat "$reqs" pyproject.toml | sha256sum | cut -d' ' -f1)
    if [ -x "$dir/bin/python" ] && [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] \
        && compgen -G "$dir/lib/python3*/site-packages/hybrid_shadows-*.dist-info" >/dev/null; then
        return 0
    fi
    if [ ! -x "$dir/bin/python" ]; then
        echo "setup: creating $dir with $py"
        if ! "$py" -m venv "$dir" 2>/dev/null; then
            rm -rf "$dir"
            local pkg
            pkg="$(basename "$py")-venv"
            if as_root && command -v apt-get >/dev/null; then
                apt_install "$pkg"
                "$py" -m venv "$dir"
            else
                die "'$py -m venv' failed; run: sudo apt-get install -y $pkg"
            fi
        fi
    fi
    echo "setup: installing $reqs into $dir (bpy is a ~400 MB download the first time)"
    quiet "$dir/bin/python" -m pip install -q --disable-pip-version-check --upgrade pip >/dev/null
    quiet "$dir/bin/python" -m pip install -q --disable-pip-version-check -r "$reqs"
    echo "setup: installing the project into $dir (pip install -e .)"
    local log  # (setuptools' notes on an editable install: shown only when it fails)
    log=$(mktemp)
    if ! "$dir/bin/python" -m pip install -q --disable-pip-version-check --no-build-isolation --no-deps -e . \
        >"$log" 2>&1; then
        cat "$log" >&2; rm -f "$log"
        die "'pip install -e .' into $dir failed (above)"
    fi
    rm -f "$log"
    echo "$want" > "$stamp"
    echo "setup: $dir done"
}
make_venv .venv "$PY" requirements.txt

PY313=""
for cand in "${PYTHON313:-}" python3.13 "${PYENV_ROOT:-$HOME/.pyenv}"/versions/3.13*/bin/python3.13; do
    [ -n "$cand" ] || continue
    if command -v "$cand" >/dev/null && "$cand" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 13))' 2>/dev/null; then
        PY313=$(command -v "$cand"); break
    fi
done
if [ -z "$PY313" ] && as_root && command -v apt-get >/dev/null && apt-cache show python3.13 >/dev/null 2>&1; then
    apt_install python3.13 python3.13-venv
    PY313=$(command -v python3.13)
fi
if [ -n "$PY313" ]; then
    make_venv .venv-bpy5 "$PY313" requirements-bpy5.txt
else
    rm -f .venv-bpy5/.requirements.sha256
    echo "setup: python3.13 not found: the bpy 5 tests are skipped (install python3.13, or set PYTHON313=/path/to/python3.13)" >&2
fi
