"""bpy-free core: scene model, bake, GPU passes, reference tracers."""
