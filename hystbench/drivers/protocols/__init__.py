"""Protocol definitions: command tables, register maps and frame codecs, with no I/O.

The drivers speak these protocols and the emulators (``hystbench.sim_backend.emulators``) answer
them, so both import this package and nothing else of each other.  Replacing an instrument's
command set (for example once the real Kistler manual is at hand) means editing one table here.
"""
