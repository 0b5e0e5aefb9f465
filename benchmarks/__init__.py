"""The benchmarks: modules run from the repository's root, ``python -m benchmarks.bench_bake``
(the add-on package as installed by ``tools/setup.sh``, ``pip install -e .``)."""
