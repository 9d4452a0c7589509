"""The live chain: ring buffer, sources, the estimation stage, pipeline, zenoh bus, and the daemon
that runs them on the bench PC."""
