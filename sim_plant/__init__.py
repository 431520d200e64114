"""The plant simulator: ground truth, sensors, the lossy link and safety accounting.

- ``core/``: pure numpy (time and randomness passed in): kinematics, encoders, sensors,
  accounting, the overhead camera's rendering.
- ``node/``: the process shell (``formation plant``).
"""
