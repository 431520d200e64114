"""The agent's process shell: Zenoh, asyncio and clocks around the firmware core.

``formation agent`` (one robot, ``main``) and ``formation agent-host`` (many, ``host_main``).
"""
