"""The in-process simulator: `formation sim` and `formation demo` (no Zenoh, deterministic)."""
