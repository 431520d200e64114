"""The coordinator's process shell (`formation coordinator`): Zenoh, asyncio, e-stop state file."""
