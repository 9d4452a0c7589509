"""The live chain: ring buffer, sources, the estimation stage, pipeline, record/replay, the zenoh bus
and the command vocabulary it speaks.  The daemon that runs it on the bench PC is
:mod:`hystbench.service`, which imports from here, never the reverse."""
