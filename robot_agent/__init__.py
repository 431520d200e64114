"""The robot agent: the firmware of one differential-drive robot and its process shell.

- ``core/``: the firmware (standard library only, no I/O, no clock reads): kinematics, the
  reference-point tracking law, repulsion, the safety filter, the estimator, the mode machine.
  It may run compiled (mypyc): ``core/_accel.py`` decides when ``robot_agent.core`` is imported.
- ``motors/``: the motor backends (device I/O: a serial RoboClaw, the bus in simulation).
- ``node/``: the process shell (Zenoh, asyncio, clocks): ``formation agent`` and
  ``formation agent-host``.
- ``buildtools/``: the compiled core's builder and its output check (never imported at run time).
"""
