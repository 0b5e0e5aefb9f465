"""The project's tools: modules run from the repository's root, ``python -m tools.shader_check``
(the add-on package as installed by ``tools/setup.sh``, ``pip install -e .``)."""
