"""The camera tracker's process shells (`formation camera`, `formation camera calibrate`)."""
