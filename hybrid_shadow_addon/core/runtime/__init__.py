"""The renderer process (both sides of its channel) and the viewport's scheduling, apart from
the GL passes (:mod:`..gpu`)."""
