"""Localization for real robots: an overhead camera tracker that publishes ``robot/<id>/pose``.

- ``core/`` (numpy + OpenCV, no Zenoh, no clock reads): ``calibration`` (the TOML file),
  ``detectors`` (tag / colour-patch detection), ``pose`` (corners -> floor pose), ``tracker``
  (plausibility, misses, stats), ``sources`` (frame sources), ``pipeline`` (one frame through all
  of them), ``rendered`` (frames rendered from the plant's truth).
- ``node/``: ``camera`` (``formation camera``), ``calibrate`` (``formation camera calibrate``),
  ``main``. See docs/localization.md.
"""
