"""The camera tracker's cores (numpy + OpenCV, no Zenoh, no clock reads)."""
