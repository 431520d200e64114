"""The ``formation`` command (``cli.py``), grouped by command family:

- ``outputs/``: what every run writes and shows (run log, metrics, figures, run file, live table);
- ``sim/``: the in-process simulator (``formation sim``, ``formation demo``);
- ``live/``: live views (``formation top``, the Foxglove server);
- ``record/``: recording, replay and reports (``formation record``, ``formation report``);
- ``launch/``: launching a fleet of processes (``formation up``, ``formation router``,
certificates);
- ``operate/``: operator tools on a running fleet (``formation fault``, the e-stop tool, fuzzing).
"""
