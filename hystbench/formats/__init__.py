"""How data leaves and enters hystbench: the recording interchange format (CSV + JSON sidecar),
MCAP logs, the raw-block codec shared by MCAP and zenoh, and all-or-nothing output files."""
