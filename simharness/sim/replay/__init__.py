"""Replay backend: recorded data sets as scenarios, the log played back or reacting to the ego."""
