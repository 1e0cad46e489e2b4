"""The SUMO backend (libsumo): network, demand, sub-lane model, crossing pedestrians, ego control, worker process.

`simulator.SumoSimulator` is the `Simulator` (one per process: libsumo is a singleton); `process.SumoProcess`
runs it in a worker process (any number, and fork-based `branch()`); `net` builds the network, `demand` the
vTypes and flows, `pedestrians` the crossings, `ego` the ego's control and reactions, `traffic` the recording.
Importing this package loads nothing: libsumo is imported by `simulator` only.
"""
