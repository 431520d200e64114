"""The coordinator: the virtual leader, the formation's slots and the role assignment.

- ``core/``: pure (numpy/scipy, no I/O, no clock: time is passed in): trajectories, formation
  geometry, matching and assignment, the standby election, the path check.
- ``node/``: the process shell (``formation coordinator``): Zenoh, asyncio, the e-stop state file.
"""
