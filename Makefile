# Two commands a user needs: `make demo` and `make test`. Both set everything up first (the add-on
# package installed editable into the environments); the tools and benchmarks run as modules from here.
PY := .venv/bin/python
export PYTHONDONTWRITEBYTECODE := 1

.PHONY: setup demo test test-fast lint bench extension clean

setup:
	@bash tools/setup.sh

DEMO_LOG := out/demo/blender.log

demo: setup
	@mkdir -p out/demo && rm -f $(DEMO_LOG)
	$(PY) -m hybrid_shadow_addon --blender-log $(DEMO_LOG) info forest
	$(PY) -m hybrid_shadow_addon --blender-log $(DEMO_LOG) render forest --output out/demo/forest.png \
		--masks-dir out/demo --stats out/demo/stats.json
	$(PY) -m hybrid_shadow_addon --blender-log $(DEMO_LOG) compare forest --resolution 320x180 --repeats 3 \
		--warmup 1 --output-dir out/demo/compare
	$(PY) -m tools.demo_blender --log $(DEMO_LOG)
	@echo "Blender's and Cycles' own output: $(DEMO_LOG)"

# the tests that run a second time on bpy 5.x (CPython 3.13, numpy 2): export, pipeline, add-on
BPY5 := .venv-bpy5/bin/python
BPY5_TESTS := tests/test_export_objects.py tests/test_export_meshes.py tests/test_export_materials.py tests/test_export_slots.py tests/test_export_lights.py tests/test_export_camera_world.py tests/test_export_load.py tests/test_scenes.py tests/test_pipeline.py tests/test_addon_engine.py \
	tests/test_addon_panels.py tests/test_addon_viewport.py tests/test_addon_border.py tests/test_bad_input.py

lint: setup
	$(PY) -m ruff check .

# the suite runs a worker per core, a test module's tests on one worker (their module fixtures);
# the tests record each shader define set they build (programs.py); the shader check compiles
# those and each optional define alone with the GL and with glslangValidator (tools/shader_check.py)
SHADER_DEFINES := out/test/shader_defines.jsonl
test: export HS_RECORD_DEFINES := $(CURDIR)/$(SHADER_DEFINES)
test: setup lint
	@mkdir -p $(dir $(SHADER_DEFINES)) && rm -f $(SHADER_DEFINES)
	$(PY) -m pytest -q -n auto --dist loadfile tests
	@if [ -f .venv-bpy5/.requirements.sha256 ]; then \
		echo "$(BPY5) -m pytest -q $(BPY5_TESTS)"; $(BPY5) -m pytest -q $(BPY5_TESTS); \
	else echo "bpy 5 tests skipped: python3.13 not found (see tools/setup.sh)"; fi
	$(PY) -m tools.shader_check --recorded $(SHADER_DEFINES)

# the inner loop: everything but the slow tests and the Cycles renders (markers: pyproject.toml)
test-fast: setup
	$(PY) -m pytest -q -n auto --dist loadfile -m "not slow and not cycles" tests

extension: setup
	$(PY) -m tools.build_extension

bench: setup
	$(PY) -m pip install -q --disable-pip-version-check -r requirements-bench.txt
	$(PY) -m benchmarks.bench_export
	$(PY) -m benchmarks.bench_bake
	$(PY) -m benchmarks.bench_pipeline
	$(PY) -m benchmarks.bench_mitsuba
	$(PY) -m benchmarks.bench_scaling
	$(PY) -m benchmarks.stiff_table --modes raytrace-high,raytrace-medium,shadowmap
	$(PY) -m benchmarks.bench_variants

clean:
	rm -rf .venv .venv-bpy5 dist build out .pytest_cache *.egg-info
