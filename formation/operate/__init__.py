"""Operator tools on a running fleet: `formation fault`, the e-stop tool, fuzzing."""
