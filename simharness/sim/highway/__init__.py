"""The highway-env backend: per-type vehicles on highway-env's road, vectorised lane-free dynamics, scripted events.

`simulator.HighwaySimulator` is the `Simulator`; `world` the highway-env environment underneath; `agents` and
`params` the agent types; `traffic` and `dynamics` the vectorised step, whose pair searches are the numba
kernels `leaders`, `room`, `crossing` and `decision`; `events` the scripted stress events.
"""
