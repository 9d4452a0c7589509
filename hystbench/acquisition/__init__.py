"""Recordings, estimators, the paper's measurement method, the real-time pipeline (ring buffer,
stages, MCAP, zenoh, the daemon), reports and the command line."""
