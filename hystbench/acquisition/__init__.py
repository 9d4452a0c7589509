"""Recordings, estimators, the paper's measurement method, reports and the command line
(later: ring buffer, pipeline, MCAP, zenoh, the daemon)."""
