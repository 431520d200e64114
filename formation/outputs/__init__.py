"""What every run writes and shows: the run log, metrics, figures, the run file, the live table."""
