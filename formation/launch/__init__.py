"""Launching a fleet of processes: `formation up`, `formation router`, certificates."""
