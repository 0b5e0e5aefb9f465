"""Tools over the core, free of bpy: ``compare`` (error against a reference, :mod:`.compare`,
:mod:`.reference`, :mod:`.report`), ``bench`` (frame rates along a camera path, :mod:`.bench`),
``render`` (one frame to files, :mod:`.render`), with :mod:`.variants`, :mod:`.metrics` and the
terminal :mod:`.progress` bar. Scenes, references and frame sources come from the caller."""
