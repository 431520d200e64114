"""Localization for real robots: an overhead camera tracker that publishes ``robot/<id>/pose``.

Pure-ish cores (numpy + OpenCV, no Zenoh, no clock reads): ``calibration`` (the TOML file),
``detectors`` (tag / colour-patch detection), ``pose`` (corners -> floor pose), ``tracker``
(plausibility, misses, stats), ``sources`` (frame sources), ``pipeline`` (one frame through all of
them), ``rendered`` (frames rendered from the plant's truth). Shells: ``node`` (``formation
camera``) and ``calibrate`` (``formation camera calibrate``). See docs/localization.md.
"""
