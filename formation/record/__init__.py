"""Recording and reports: `formation record` (MCAP), replay, `formation report`, run collector."""
