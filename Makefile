# Two commands a user needs: `make demo` and `make test`. Both set everything up first.
PY := .venv/bin/python
export PYTHONDONTWRITEBYTECODE := 1

.PHONY: setup demo test bench extension clean

setup:
	@bash tools/setup.sh

demo: setup
	$(PY) -m hybrid_shadow_addon info forest
	@mkdir -p out/demo
	$(PY) -m hybrid_shadow_addon render forest --output out/demo/forest.png \
		--masks-dir out/demo --stats out/demo/stats.json
	$(PY) -m hybrid_shadow_addon compare forest --resolution 320x180 --repeats 3 --warmup 1 \
		--output-dir out/demo/compare
	$(PY) tools/demo_blender.py

test: setup
	$(PY) -m pytest -q tests

extension: setup
	$(PY) tools/build_extension.py

bench: setup
	$(PY) -m pip install -q --disable-pip-version-check -r requirements-bench.txt
	$(PY) benchmarks/bench_export.py
	$(PY) benchmarks/bench_bake.py
	$(PY) benchmarks/bench_pipeline.py
	$(PY) benchmarks/bench_mitsuba.py
	$(PY) benchmarks/bench_scaling.py
	$(PY) benchmarks/stiff_table.py --modes raytrace-high,raytrace-medium,shadowmap
	$(PY) benchmarks/bench_variants.py

clean:
	rm -rf .venv dist build out .pytest_cache
