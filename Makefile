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
	$(PY) benchmarks/run_all.py

clean:
	rm -rf .venv dist build out .pytest_cache
