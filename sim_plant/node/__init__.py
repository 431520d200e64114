"""The plant simulator's process shell (`formation plant`)."""
