"""Live views of a running fleet: `formation top` and the Foxglove WebSocket server."""
